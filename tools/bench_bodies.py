"""Time and memory of simulated runs of large swarms with bodies, by size and phase (docs/benchmarks.md, "Bodies at scale").

    PYTHONPATH=. python tools/bench_bodies.py --sizes 100,300,1000,3000,10000 --configs 1 [--method no-anchors] [--localizer joint]

Per size, in a process of its own (so its peak memory is its own): the random trajectory (drawn with bodies kept
apart), the validation of its changes (``validate_passable``), the whole run (``inchworm.simulate``: the
validation again, selection, body regrouping, steps, localization), then the contacts counted afterwards, in wall
seconds; the CPU seconds of the whole and, within the run, of the anchor selection (the strategy's ``plan``), the
body regrouping (``clear_plan``), the sensing (``SimulatedSwarm.observe``) and the localization
(``localize_observable``) (CPU: less sensitive to other jobs than wall times on a shared machine); the steps
taken and added for bodies; the peak resident memory. Prints one row per size and, last, one JSON object.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

PHASES = {"select_s": ("coordinator.strategies", ("SelectedStrategy", "FixedPlanStrategy", "HeuristicStrategy"), "plan"),
          "regroup_s": ("coordinator.executor", (), "clear_plan"),
          "sense_s": ("runtime.models.simulation", ("SimulatedSwarm",), "observe"),
          "localize_s": ("coordinator.executor", (), "localize_observable")}


@contextmanager
def timed_phases(spent: dict[str, float]) -> Iterator[None]:
    """Add the CPU time (the process's: on a shared machine it depends less on other jobs than the wall time) spent in
    each of ``PHASES`` (module, classes (none: a module function), name) to ``spent``."""
    import importlib  # noqa: PLC0415

    undo = []
    for key, (module, classes, name) in PHASES.items():
        spent[key] = 0.0
        for owner in [getattr(importlib.import_module(module), c) for c in classes] or [importlib.import_module(module)]:
            original = getattr(owner, name)

            def wrapper(*args: Any, _original: Any = original, _key: str = key, **kwargs: Any) -> Any:
                t = time.process_time()
                try:
                    return _original(*args, **kwargs)
                finally:
                    spent[_key] += time.process_time() - t

            setattr(owner, name, wrapper)
            undo.append((owner, name, original))
    try:
        yield
    finally:
        for owner, name, original in undo:
            setattr(owner, name, original)


def run(n: int, configs: int, method: str, localizer: str, seed: int) -> dict[str, Any]:
    """One size's row (this process)."""
    from inchworm.simulation import simulate  # noqa: PLC0415
    from runtime.models.config import ModelConfig  # noqa: PLC0415
    from runtime.models.trajectory import body_spacing, random_trajectory, validate_passable  # noqa: PLC0415

    cfg = ModelConfig()
    spent: dict[str, float] = {}
    with timed_phases(spent):
        t0, c0 = time.perf_counter(), time.process_time()
        traj = random_trajectory(n, configs, np.random.default_rng(seed), sensing_range=cfg.sensing_range_m, **body_spacing(cfg))
        t1 = time.perf_counter()
        validate_passable(traj, cfg)
        t2 = time.perf_counter()
        result = simulate(traj, method=method, model=cfg, localizer=localizer, seed=seed)
        t3 = time.perf_counter()
        contacts = result.contacts(cfg.robot_radius_m)
        t4, c4 = time.perf_counter(), time.process_time()
    return {"robots": n, "configs": configs, "trajectory_s": t1 - t0, "validate_s": t2 - t1, "run_s": t3 - t2, **spent,
            "contacts_s": t4 - t3, "total_s": t4 - t0, "cpu_s": c4 - c0, "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
            "steps": int(result.steps_per_config().sum()), "steps_added": result.steps_added(), "contacts": len(contacts),
            "pf": result.pf()}


COLUMNS = (("robots", "robots", 7, "d"), ("trajectory_s", "traj s", 7, ".2f"), ("validate_s", "valid s", 7, ".2f"),
           ("run_s", "run s", 8, ".1f"), ("select_s", "select cpu", 10, ".1f"), ("regroup_s", "regroup cpu", 11, ".1f"),
           ("sense_s", "sense cpu", 9, ".1f"), ("localize_s", "localize cpu", 12, ".1f"), ("contacts_s", "contacts s", 10, ".2f"),
           ("total_s", "total s", 8, ".1f"), ("cpu_s", "cpu s", 8, ".1f"), ("peak_rss_mb", "RSS MB", 7, ".0f"),
           ("steps", "steps", 6, "d"), ("steps_added", "added", 6, "d"), ("contacts", "contacts", 8, "d"))


def sizes(text: str) -> list[int]:
    """``--sizes``: comma-separated robot counts, each at least 2."""
    try:
        out = [int(s) for s in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"--sizes must be comma-separated integers, got {text!r}") from None
    if not out or min(out) < 2:
        raise argparse.ArgumentTypeError(f"--sizes: every size must be at least 2 robots, got {text!r}")
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=sizes, default=sizes("200,1000"), help="robot counts, comma-separated (default 200,1000)")
    parser.add_argument("--configs", type=int, default=1)
    parser.add_argument("--method", default="inchworm")
    parser.add_argument("--localizer", default="paper")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--one", action="store_true", help=argparse.SUPPRESS)  # a child: run the one size, print its row
    args = parser.parse_args()
    if args.one:
        print(json.dumps(run(args.sizes[0], args.configs, args.method, args.localizer, args.seed)))
        return
    rows = []
    print(" ".join(f"{title:>{width}}" for _, title, width, _ in COLUMNS), flush=True)
    for n in args.sizes:
        child = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--one", "--sizes", str(n), "--configs", str(args.configs),
                                "--method", args.method, "--localizer", args.localizer, "--seed", str(args.seed)],
                               capture_output=True, text=True, check=False)
        if child.returncode:
            sys.exit(f"bench_bodies: {n} robots failed: {child.stderr.strip().splitlines()[-1] if child.stderr.strip() else child.returncode}")
        r = json.loads(child.stdout.strip().splitlines()[-1])
        rows.append(r)
        print(" ".join(f"{r[key]:>{width}{fmt}}" for key, _, width, fmt in COLUMNS), flush=True)
    print(json.dumps({"method": args.method, "localizer": args.localizer, "seed": args.seed, "rows": rows}))


if __name__ == "__main__":
    main()
