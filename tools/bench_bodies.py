"""Wall time of simulated runs of large swarms with bodies, by phase (docs/benchmarks.md, "Bodies at scale").

    PYTHONPATH=. python tools/bench_bodies.py --sizes 200,1000,10000 --configs 1 [--method no-anchors] [--localizer joint]

Per size: the random trajectory (drawn with bodies kept apart), the validation of its changes
(``validate_passable``), the whole run (``inchworm.simulate``: the validation again, selection, body regrouping, steps,
localization), within it the regrouping (``clear_plan``), and the contacts counted afterwards; the
steps taken and added for bodies; the process's CPU time (less sensitive to other jobs than the wall
times on a shared machine). Prints one row per size and, last, one JSON object.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

import coordinator.executor as executor
from inchworm.simulation import simulate
from runtime.models.config import ModelConfig
from runtime.models.trajectory import body_spacing, random_trajectory, validate_passable


def run(n: int, configs: int, method: str, localizer: str, seed: int) -> dict:
    cfg = ModelConfig()
    spent = {"regroup_s": 0.0}
    clear_plan = executor.clear_plan

    def timed(*args, **kwargs):  # the executor's regrouping, timed
        t = time.perf_counter()
        try:
            return clear_plan(*args, **kwargs)
        finally:
            spent["regroup_s"] += time.perf_counter() - t

    executor.clear_plan = timed
    try:
        t0, c0 = time.perf_counter(), time.process_time()
        traj = random_trajectory(n, configs, np.random.default_rng(seed), sensing_range=cfg.sensing_range_m, **body_spacing(cfg))
        t1 = time.perf_counter()
        validate_passable(traj, cfg)
        t2 = time.perf_counter()
        result = simulate(traj, method=method, model=cfg, localizer=localizer, seed=seed)
        t3 = time.perf_counter()
        contacts = result.contacts(cfg.robot_radius_m)
        t4, c4 = time.perf_counter(), time.process_time()
    finally:
        executor.clear_plan = clear_plan
    return {"robots": n, "configs": configs, "trajectory_s": t1 - t0, "validate_s": t2 - t1, "run_s": t3 - t2,
            "regroup_s": spent["regroup_s"], "contacts_s": t4 - t3, "total_s": t4 - t0, "cpu_s": c4 - c0,
            "steps": int(result.steps_per_config().sum()), "steps_added": result.steps_added(), "contacts": len(contacts)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="200,1000")
    parser.add_argument("--configs", type=int, default=1)
    parser.add_argument("--method", default="inchworm")
    parser.add_argument("--localizer", default="paper")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    rows = []
    print(f"{'robots':>7} {'traj s':>7} {'valid s':>7} {'run s':>8} {'regroup s':>9} {'contacts s':>10} {'total s':>8} "
          f"{'cpu s':>8} {'steps':>6} {'added':>6} {'contacts':>8}", flush=True)
    for n in (int(s) for s in args.sizes.split(",")):
        r = run(n, args.configs, args.method, args.localizer, args.seed)
        rows.append(r)
        print(f"{n:>7} {r['trajectory_s']:>7.2f} {r['validate_s']:>7.2f} {r['run_s']:>8.2f} {r['regroup_s']:>9.2f} "
              f"{r['contacts_s']:>10.2f} {r['total_s']:>8.2f} {r['cpu_s']:>8.2f} "
              f"{r['steps']:>6} {r['steps_added']:>6} {r['contacts']:>8}", flush=True)
    print(json.dumps({"method": args.method, "localizer": args.localizer, "rows": rows}))


if __name__ == "__main__":
    main()
