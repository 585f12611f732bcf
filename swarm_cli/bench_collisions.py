"""``swarm bench collisions``: contacts between robot bodies, planned with bodies and as points.

Every method and localizer runs ``--trajectories`` random trajectories of ``--configs``
configurations (``swarm compare``'s scheme, in process, the same seeds) twice: planned with
bodies of ``--robot-radius`` (the constraint of ``docs/bodies.md``) and planned as the paper's
point robots (radius 0). Contacts are counted at ``--robot-radius`` either way
(``RunResult.contacts``: true centres closer than two radii at some time of a step). The
trajectories are drawn for bodies (kept passable), so both rows run the same ones.
Per row: contacts per 100 configuration changes, the percentage of changes with a contact,
steps per configuration (speed, Eq. 6-7) and the mean P_f (Eq. 24). The last line is one
JSON object (``--json``)::

    {"radius_m": R, "trajectories": T, "configs": C, "rows": [{"method": M, "localizer": L,
     "bodies": true|false, "contacts_per_100": X, "configs_with_contact_pct": Y,
     "steps_per_config": S, "pf_mean": P}, ...]}
"""

from __future__ import annotations

import argparse
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace

import numpy as np

from coordinator.strategies import METHODS
from runtime.errors import SwarmInputError
from runtime.models.trajectory import body_spacing, random_trajectory
from swarm_cli.options import add_selection_options, add_model_options, add_json_option, add_workers_option, model_config, print_json, selection_config
from inchworm.progress import Progress

LOCALIZERS = ("paper", "joint")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("collisions", help="contacts between robot bodies per method, planned with bodies and as points")
    p.add_argument("--robots", type=int, default=10, help="n_r (default 10)")
    p.add_argument("--trajectories", type=int, default=20, help="random trajectories (default 20)")
    p.add_argument("--configs", type=int, default=20, help="configurations per trajectory (default 20)")
    p.add_argument("--methods", default=",".join(METHODS), help="comma-separated methods (default: all)")
    p.add_argument("--localizers", default="paper", help="comma-separated localizers: paper, joint (default paper)")
    p.add_argument("--seed", type=int, default=0, help="trajectory t uses seed + t (default 0)")
    add_workers_option(p)
    add_selection_options(p)
    add_model_options(p)
    add_json_option(p)
    p.set_defaults(run=run)


def run_one(job: tuple) -> dict:
    """One (trajectory, method, localizer, planned with bodies or not) run; top-level for worker processes."""
    from coordinator.simulate import simulate  # noqa: PLC0415

    t, method, localizer, bodies, robots, configs, seed, cfg, selection = job
    radius = cfg.robot_radius_m
    traj = random_trajectory(robots, configs, np.random.default_rng([seed, t]), sensing_range=cfg.sensing_range_m, **body_spacing(cfg))
    planned = cfg if bodies else replace(cfg, robot_radius_m=0.0)
    result = simulate(traj, method, planned, localizer=localizer, selection=selection, seed=seed + t)
    contacts = result.contacts(radius)
    return {
        "method": method, "localizer": localizer, "bodies": bodies, "contacts": len(contacts),
        "configs_with_contact": len({c.config for c in contacts}), "configs": len(result.configs),
        "steps": int(result.steps_per_config().sum()), "steps_added": result.steps_added(),
        "unclear": sum(1 for c in result.configs if c.regrouped is not None and c.regrouped.unclear),
        "min_distance": min((c.distance for c in contacts), default=float("nan")), "pf": result.pf(),
    }


def summarise(runs: list[dict], keys: list[tuple[str, str, bool]]) -> list[dict]:
    """One row per (method, localizer, bodies) with the contract's keys, plus the extras the table prints."""
    rows = []
    for method, localizer, bodies in keys:
        mine = [r for r in runs if (r["method"], r["localizer"], r["bodies"]) == (method, localizer, bodies)]
        changes = sum(r["configs"] for r in mine)
        rows.append({
            "method": method, "localizer": localizer, "bodies": bodies,
            "contacts_per_100": 100.0 * sum(r["contacts"] for r in mine) / changes,
            "configs_with_contact_pct": 100.0 * sum(r["configs_with_contact"] for r in mine) / changes,
            "steps_per_config": sum(r["steps"] for r in mine) / changes,
            "pf_mean": float(np.mean([r["pf"] for r in mine])),
            "_steps_added": sum(r["steps_added"] for r in mine), "_unclear": sum(r["unclear"] for r in mine),
        })
    return rows


def run(args: argparse.Namespace) -> int:
    cfg = model_config(args)
    if cfg.robot_radius_m <= 0:
        raise SwarmInputError("--robot-radius must be > 0 for counting contacts between bodies")
    if args.trajectories < 1 or args.configs < 1 or args.robots < 2:
        raise SwarmInputError("--trajectories and --configs must be >= 1 and --robots >= 2")
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    localizers = [v.strip() for v in args.localizers.split(",") if v.strip()]
    if not methods or any(m not in METHODS for m in methods):
        raise SwarmInputError(f"--methods must list methods of {', '.join(METHODS)}, got {args.methods!r}")
    if not localizers or any(v not in LOCALIZERS for v in localizers):
        raise SwarmInputError(f"--localizers must list {' and/or '.join(LOCALIZERS)}, got {args.localizers!r}")
    selection = selection_config(args)
    keys = [(m, v, b) for v in localizers for m in methods for b in (True, False)]
    jobs = [(t, m, v, b, args.robots, args.configs, args.seed, cfg, selection) for m, v, b in keys for t in range(args.trajectories)]
    progress = Progress(len(jobs), "bench collisions")
    runs = []
    with ProcessPoolExecutor(max_workers=max(1, args.workers)) as pool:
        for run_row in pool.map(run_one, jobs):
            runs.append(run_row)
            progress(len(runs))
    rows = summarise(runs, keys)
    print(f"radius {cfg.robot_radius_m:g} m, {args.trajectories} trajectories x {args.configs} configurations, n_r = {args.robots}")
    print(f"{'method':<22} {'localizer':<9} {'planned':<7} {'contacts/100':>12} {'changes %':>9} {'steps':>6} {'added':>6} {'unclear':>7} {'P_f':>8}")
    for r in rows:
        print(f"{r['method']:<22} {r['localizer']:<9} {'bodies' if r['bodies'] else 'points':<7} {r['contacts_per_100']:>12.2f} "
              f"{r['configs_with_contact_pct']:>9.2f} {r['steps_per_config']:>6.2f} {r['_steps_added']:>6} {r['_unclear']:>7} {r['pf_mean']:>8.4f}")
    print("added: steps the body constraint added over all runs; unclear: configuration changes with robots no order kept clear")
    if args.json:
        print_json({"radius_m": cfg.robot_radius_m, "trajectories": args.trajectories, "configs": args.configs,
                    "rows": [{k: v for k, v in r.items() if not k.startswith("_")} for r in rows]})
    return 0
