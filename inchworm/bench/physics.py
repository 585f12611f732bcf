"""How well a plan made with the noise model predicts the physical world (``swarm bench physics``, docs/physics.md).

Each of ``trajectories`` random trajectories (``swarm compare``'s scheme, the same seeds) runs ``method`` twice
with the same model (e.g. the one ``swarm calibrate`` fitted to a physics run): in the noise model's world,
where the plan's assumptions hold (the prediction), and in the physical world (the measurement). Per world:
P_f (Eq. 24), the final localization error e_l (Eq. 8) against the anchor selection's Monte Carlo estimate
of it for the chosen plans (the planner's own prediction of one change from a known start, where it searched and a
clear plan existed: a lower bound of the accumulated e_l), and contacts per 100
configuration changes: the plans keep every pair 2R + margin apart (docs/bodies.md), so zero are planned;
the model's world counts bodies closer than 2R along the straight paths between true poses, the physical
world the bodies that touched (and drives that stalled). ``to_json()``::

    {"trajectories": T, "configs": C, "robots": N, "method": M, "rows": [{"world": "model"|"physics",
     "pf_mean": P, "pf_sd": S, "e_l_mean": E, "e_l_planned_mean": E0, "contacts_per_100": X,
     "stuck_per_100": Y}, ...], "pf_ratio": physics P_f mean / model P_f mean}
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from typing import Any

import numpy as np

from coordinator.strategies import METHODS
from inchworm.bench import BenchResult
from inchworm.bench.options import PhysicsBenchOptions
from inchworm.runner import pool_localizers, process_context, register_localizers
from runtime.errors import OptionError
from runtime.models.trajectory import body_spacing, random_trajectory

WORLDS = ("model", "physics")


def run_one(job: tuple[int, str, PhysicsBenchOptions]) -> dict[str, Any]:
    """One (trajectory, world) run; top-level for worker processes."""
    from inchworm.simulation import simulate  # noqa: PLC0415
    from runtime.world.params import parse_physics_params  # noqa: PLC0415
    from runtime.world.physics import Contact, Stuck  # noqa: PLC0415

    t, world, o = job
    cfg = o.run.model
    traj = random_trajectory(o.robots, o.configs, np.random.default_rng([o.seed, t]), sensing_range=cfg.sensing_range_m,
                             **body_spacing(cfg))
    params = parse_physics_params(list(o.physics), cfg) if world == "physics" else None
    result = simulate(traj, method=o.method, model=cfg, localizer=o.run.localizer, selection=o.run.selection, seed=o.seed + t,
                      world=world, physics=params)
    planned = [next(s.e_l for s in c.selection.scores if s.n_anchors == c.selection.n_anchors)
               for c in result.configs if c.selection is not None and c.selection.scores]
    planned = [x for x in planned if np.isfinite(x)]  # inf: no plan was clear and the fallback was taken (docs/bodies.md)
    events = [e for _, e in result.world_events]
    return {"world": world, "pf": result.pf(), "e_l": float(result.localization_errors()[-1]),
            "e_l_planned": [float(x) for x in planned], "e_l_all": [float(x) for x in result.localization_errors()],
            "configs": len(result.configs),
            "contacts": sum(isinstance(e, Contact) for e in events) if world == "physics" else len(result.contacts(cfg.robot_radius_m)),
            "stuck": sum(isinstance(e, Stuck) for e in events)}


def check(o: PhysicsBenchOptions) -> None:
    for name, low in (("trajectories", 1), ("configs", 1), ("robots", 2)):
        if getattr(o, name) < low:
            raise OptionError(name, f"must be >= {low}, got {getattr(o, name)}", o)
    if o.method not in METHODS:
        raise OptionError("method", f"must be one of {', '.join(METHODS)}, got {o.method!r}", o)
    from runtime.world.params import parse_physics_params  # noqa: PLC0415 - the physics extra
    from runtime.world.physics import require_pymunk  # noqa: PLC0415

    require_pymunk()
    parse_physics_params(list(o.physics), o.run.model)


def bench_physics(options: PhysicsBenchOptions | None = None, progress: Callable[[int], None] | None = None) -> BenchResult:
    """Run every trajectory in both worlds (``options`` None: the defaults); ``progress`` is told the runs done."""
    o = options or PhysicsBenchOptions()
    check(o)
    jobs = [(t, w, o) for t in range(o.trajectories) for w in WORLDS]
    runs: list[dict[str, Any]] = []
    with ProcessPoolExecutor(max_workers=max(1, o.workers), mp_context=process_context(),
                             initializer=register_localizers, initargs=(pool_localizers(),)) as pool:
        for row in pool.map(run_one, jobs):
            runs.append(row)
            if progress:
                progress(len(runs))
    rows = []
    for world in WORLDS:
        mine = [r for r in runs if r["world"] == world]
        changes = sum(r["configs"] for r in mine)
        planned = [x for r in mine for x in r["e_l_planned"]]
        rows.append({"world": world, "pf_mean": float(np.mean([r["pf"] for r in mine])), "pf_sd": float(np.std([r["pf"] for r in mine], ddof=1))
                     if len(mine) > 1 else 0.0, "e_l_mean": float(np.mean([x for r in mine for x in r["e_l_all"]])),
                     "e_l_planned_mean": float(np.mean(planned)) if planned else None,
                     "contacts_per_100": 100.0 * sum(r["contacts"] for r in mine) / changes,
                     "stuck_per_100": 100.0 * sum(r["stuck"] for r in mine) / changes})
    cfg = o.run.model
    lines = [f"{o.method}, {o.trajectories} trajectories x {o.configs} configurations, n_r = {o.robots}, radius {cfg.robot_radius_m:g} m; "
             f"model: turn {np.degrees(cfg.turn_sigma_rad):.2f} deg, drive {100 * cfg.drive_sigma_frac:.2f} %, range "
             f"{1e3 * cfg.range_sigma_m:.1f} mm, bearing {np.degrees(cfg.bearing_sigma_rad):.2f} deg",
             f"{'world':<8} {'P_f mean':>9} {'P_f sd':>8} {'e_l (mm)':>9} {'e_l planned (mm)':>17} {'contacts/100':>12} {'stalls/100':>10}"]
    for r in rows:
        e0 = "-" if r["e_l_planned_mean"] is None else f"{1e3 * r['e_l_planned_mean']:.2f}"
        lines.append(f"{r['world']:<8} {r['pf_mean']:>9.4f} {r['pf_sd']:>8.4f} {1e3 * r['e_l_mean']:>9.2f} {e0:>17} "
                     f"{r['contacts_per_100']:>12.2f} {r['stuck_per_100']:>10.2f}")
    ratio = rows[1]["pf_mean"] / rows[0]["pf_mean"] if rows[0]["pf_mean"] > 0 else None
    lines.append("planned contacts: 0 (every planned step keeps 2R + margin, docs/bodies.md); model: bodies closer than 2R on the "
                 "straight paths between true poses; physics: bodies that touched"
                 + ("" if ratio is None else f"; P_f physics / model = {ratio:.2f}"))
    summary = {"trajectories": o.trajectories, "configs": o.configs, "robots": o.robots, "method": o.method, "rows": rows, "pf_ratio": ratio}
    return BenchResult(rows, summary, "\n".join(lines), "world", "pf_mean", "P_f", "the noise model's prediction and the physical world")
