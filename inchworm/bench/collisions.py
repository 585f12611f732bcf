"""Contacts between robot bodies, planned with bodies and as points (``swarm bench collisions``, docs/bodies.md).

Every method and localizer runs ``trajectories`` random trajectories of ``configs``
configurations (``swarm compare``'s scheme, in process, the same seeds) twice: planned with
bodies of the model's ``robot_radius_m`` (the constraint of ``docs/bodies.md``) and planned as
the paper's point robots (radius 0). Contacts are counted at that radius either way
(``RunResult.contacts``: true centres closer than two radii at some time of a step). The
trajectories are drawn for bodies (kept passable), so both rows run the same ones.
Every row is run at each of ``noise_scales``: the model's motion noise (turn sigma and drive
sigma fraction) times that factor (x3: 9 deg and 0.15 from the defaults), the trajectories
drawn and the plans made for that noise.
Per row: contacts per 100 configuration changes, the percentage of changes with a contact,
steps per configuration (speed, Eq. 6-7) and the mean P_f (Eq. 24). ``to_json()``::

    {"radius_m": R, "trajectories": T, "configs": C, "rows": [{"method": M, "localizer": L,
     "bodies": true|false, "contacts_per_100": X, "configs_with_contact_pct": Y,
     "steps_per_config": S, "pf_mean": P, "noise_scale": K, "steps_added": A, "unclear_changes": U,
     "raised_bound_changes": B, "leg_changes": G, "staging_stops": S, "stopped_short": H,
     "stopped_short_changes": J, "holds": W, "corrections": K, "legs_cut": Q, "deferred": D}, ...]}

``steps_added``: steps the chance constraint added over all runs of the row; ``raised_bound_changes``: configuration
changes where no order kept the contact bound (``CONTACT_BOUND`` per pair and step) and it was raised for some
robots; ``unclear_changes``: changes with robots no order kept within the highest bound (moved one at a time);
``leg_changes``: changes whose movers drove in approach legs (``coordinator.legs``), ``staging_stops``: the legs driven
to a staging point (one per robot and stop; their steps are in ``steps_added`` and ``steps_per_config``);
``stopped_short``: robots the legs stopped short of their desired position (one per robot and change: their place is
at risk even reached with no motion noise, or their way is blocked by a robot standing for the rest of the change),
``stopped_short_changes``: changes with such a robot; ``holds``: legs a
robot waited where it stood for a neighbour (one per robot and leg: a pair separated in time, ``coordinator.legs``);
``corrections``: legs a robot drove back towards its goal after standing at risk by the new estimate (one per robot and
leg, ``coordinator.legs.corrections``); ``legs_cut``: legs that ended before their last group, at a touch or before a
step at risk (``coordinator.legs.new_touches``, ``deferred_movers``); ``deferred``: robots that stood in their step of a
leg because it was at risk (one per robot and leg).
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from typing import TYPE_CHECKING, Any, TypeAlias

import numpy as np

from inchworm.bench import BenchResult
from inchworm.bench.options import CollisionsBenchOptions
from inchworm.runner import pool_localizers, process_context, register_localizers
from runtime.models.bodies import BOUND_LEVELS, CONTACT_BOUND
from runtime.models.config import ModelConfig
from runtime.models.trajectory import body_spacing, random_trajectory

if TYPE_CHECKING:
    from coordinator.selection.selector import SelectionConfig

# (trajectory, method, localizer, planned with bodies, robots, configs, seed, model, selection, noise scale)
Job: TypeAlias = tuple[int, str, str, bool, int, int, int, ModelConfig, "SelectionConfig", float]


def scaled(cfg: ModelConfig, factor: float) -> ModelConfig:
    """``cfg`` with its motion noise (turn sigma, drive sigma fraction) times ``factor``."""
    return replace(cfg, turn_sigma_rad=cfg.turn_sigma_rad * factor, drive_sigma_frac=cfg.drive_sigma_frac * factor)


def run_one(job: Job) -> dict[str, Any]:
    """One (trajectory, method, localizer, planned with bodies or not) run; top-level for worker processes."""
    from coordinator.simulate import simulate  # noqa: PLC0415

    t, method, localizer, bodies, robots, configs, seed, cfg, selection, scale = job
    cfg = scaled(cfg, scale)
    radius = cfg.robot_radius_m
    traj = random_trajectory(robots, configs, np.random.default_rng([seed, t]), sensing_range=cfg.sensing_range_m, **body_spacing(cfg))
    planned = cfg if bodies else replace(cfg, robot_radius_m=0.0)
    result = simulate(traj, method, planned, localizer=localizer, selection=selection, seed=seed + t)
    contacts, short = result.contacts(radius), result.stopped_short()
    return {
        "method": method, "localizer": localizer, "bodies": bodies, "noise_scale": scale, "contacts": len(contacts),
        "configs_with_contact": len({c.config for c in contacts}), "configs": len(result.configs),
        "steps": int(result.steps_per_config().sum()), "steps_added": result.steps_added(),
        "unclear": sum(1 for c in result.configs if c.regrouped is not None and c.regrouped.unclear),
        "raised": sum(1 for c in result.configs if c.regrouped is not None and c.regrouped.bound > CONTACT_BOUND),
        "min_distance": min((c.distance for c in contacts), default=float("nan")), "pf": result.pf(),
        "staging_stops": result.staging_stops(), "leg_changes": sum(1 for c in result.configs if c.legs),
        "stopped_short": sum(len(s) for s in short), "stopped_short_changes": sum(1 for s in short if s),
        "holds": result.holds(), "corrections": result.corrections(), "legs_cut": sum(c.legs_cut for c in result.configs),
        "deferred": sum(c.deferred for c in result.configs),
    }


def summarise(runs: list[dict[str, Any]], keys: list[tuple[str, str, bool, float]]) -> list[dict[str, Any]]:
    """One row per (method, localizer, bodies, noise scale) with the contract's keys, plus the extras the table prints."""
    rows = []
    for method, localizer, bodies, scale in keys:
        mine = [r for r in runs if (r["method"], r["localizer"], r["bodies"], r["noise_scale"]) == (method, localizer, bodies, scale)]
        changes = sum(r["configs"] for r in mine)
        rows.append({
            "method": method, "localizer": localizer, "bodies": bodies,
            "contacts_per_100": 100.0 * sum(r["contacts"] for r in mine) / changes,
            "configs_with_contact_pct": 100.0 * sum(r["configs_with_contact"] for r in mine) / changes,
            "steps_per_config": sum(r["steps"] for r in mine) / changes,
            "pf_mean": float(np.mean([r["pf"] for r in mine])), "noise_scale": scale,
            "steps_added": sum(r["steps_added"] for r in mine), "unclear_changes": sum(r["unclear"] for r in mine),
            "raised_bound_changes": sum(r["raised"] for r in mine),
            "leg_changes": sum(r["leg_changes"] for r in mine), "staging_stops": sum(r["staging_stops"] for r in mine),
            "stopped_short": sum(r["stopped_short"] for r in mine),
            "stopped_short_changes": sum(r["stopped_short_changes"] for r in mine),
            "holds": sum(r["holds"] for r in mine), "corrections": sum(r["corrections"] for r in mine),
            "legs_cut": sum(r["legs_cut"] for r in mine), "deferred": sum(r["deferred"] for r in mine),
        })
    return rows


def bench_collisions(options: CollisionsBenchOptions | None = None, progress: Callable[[int], None] | None = None) -> BenchResult:
    """Run every (method, localizer, bodies or points) on every trajectory (``options`` None: the defaults); ``progress``
    is told the runs done."""
    o = options or CollisionsBenchOptions()
    cfg = o.run.model
    keys = [(m, v, b, k) for k in o.noise_scales for v in o.localizers for m in o.methods for b in (True, False)]
    jobs = [(t, m, v, b, o.robots, o.configs, o.seed, cfg, o.run.selection, k) for m, v, b, k in keys for t in range(o.trajectories)]
    runs: list[dict[str, Any]] = []
    with ProcessPoolExecutor(max_workers=max(1, o.workers), mp_context=process_context(),
                             initializer=register_localizers, initargs=(pool_localizers(),)) as pool:
        for run_row in pool.map(run_one, jobs):
            runs.append(run_row)
            if progress:
                progress(len(runs))
    rows = summarise(runs, keys)
    lines = [f"radius {cfg.robot_radius_m:g} m, {o.trajectories} trajectories x {o.configs} configurations, n_r = {o.robots}; "
             f"noise: motion noise x the model's ({np.degrees(cfg.turn_sigma_rad):g} deg, {cfg.drive_sigma_frac:g})",
             f"{'noise':>5} {'method':<22} {'localizer':<9} {'planned':<7} {'contacts/100':>12} {'changes %':>9} {'steps':>6} {'added':>6} "
             f"{'unclear':>7} {'raised':>6} {'legs':>5} {'stops':>6} {'waits':>6} {'fixes':>5} {'cut':>4} {'short':>5} {'P_f':>8}"]
    for r in rows:
        lines.append(f"{r['noise_scale']:>5g} {r['method']:<22} {r['localizer']:<9} {'bodies' if r['bodies'] else 'points':<7} "
                     f"{r['contacts_per_100']:>12.2f} "
                     f"{r['configs_with_contact_pct']:>9.2f} {r['steps_per_config']:>6.2f} {r['steps_added']:>6} "
                     f"{r['unclear_changes']:>7} {r['raised_bound_changes']:>6} {r['leg_changes']:>5} {r['staging_stops']:>6} "
                     f"{r['holds']:>6} {r['corrections']:>5} {r['legs_cut']:>4} "
                     f"{r['stopped_short']:>5} {r['pf_mean']:>8.4f}")
    lines.append(f"added: steps the body constraint added over all runs; raised: configuration changes where no order kept the contact "
                 f"bound {CONTACT_BOUND:g} per pair and step for some robots (raised for them); unclear: changes with robots no order "
                 f"kept within {max(BOUND_LEVELS):g} (moved one at a time); legs: changes whose movers drove in approach legs, stops: "
                 f"approach legs driven to a staging point; waits: legs a robot waited in for a neighbour; fixes: correction legs of a "
                 f"robot left at risk; cut: legs cut short (a touch, or the next step at risk); short: robots stopped "
                 f"short of their targets (at risk there even with no motion noise, or blocked by a standing robot)")
    public = [{k: v for k, v in r.items() if not k.startswith("_")} for r in rows]
    summary = {"radius_m": cfg.robot_radius_m, "trajectories": o.trajectories, "configs": o.configs, "rows": public}
    return BenchResult(public, summary, "\n".join(lines), "method", "contacts_per_100", "contacts per 100 changes",
                       "contacts between robot bodies")
