"""``swarm bench select``: wall time of one full anchor selection (outer + inner loop, Section 4.2).

For each swarm size a random start and desired configuration (one Section-7 step) are
drawn and ``AnchorSelector.select`` runs with the default budget (Monte Carlo samples,
genetic population and generations as in ``swarm sim``). The process is pinned to one
core (``--all-cores`` lifts that), as the targets are stated for one core.
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import sys
import time

import numpy as np

from runtime.errors import SwarmInputError
from runtime.models.state import SwarmEstimate
from runtime.models.trajectory import body_spacing, random_trajectory
from swarm_cli.options import add_simulation_options, model_config, parse_list, print_json, selection_config


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("select", help="time of one full anchor selection for n_r = 10, 30, 100")
    p.add_argument("--sizes", default="10,30,100", help="comma-separated swarm sizes (default 10,30,100)")
    p.add_argument("--repeats", type=int, default=3, help="selections per size, each on a new random step (default 3)")
    p.add_argument("--seed", type=int, default=0, help="seed of the random steps (default 0)")
    p.add_argument("--all-cores", action="store_true", help="do not pin the process to one core")
    add_simulation_options(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from coordinator.selection.selector import AnchorSelector  # noqa: PLC0415
    sizes = parse_list(args.sizes, "--sizes", int, 2)
    if args.repeats < 1:
        raise SwarmInputError(f"--repeats must be >= 1, got {args.repeats}")
    if not args.all_cores and hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    cfg, selection = model_config(args), selection_config(args)
    results = []
    print(f"{'n':>5} {'s_median':>9} {'s_min':>7} {'s_max':>7} {'n_a chosen':>10} {'plans evaluated':>16}")
    for n in sizes:
        times, chosen, evaluations = [], [], []
        for r in range(args.repeats):
            print(f"n={n} selection {r + 1}/{args.repeats}", file=sys.stderr, flush=True)
            traj = random_trajectory(n, 1, np.random.default_rng([args.seed, n, r]), sensing_range=cfg.sensing_range_m, **body_spacing(cfg))
            estimate = SwarmEstimate.isotropic(traj.ids, traj.initial_poses, 0.01, math.radians(2.0))
            selector = AnchorSelector(cfg, args.localizer, selection, seed=args.seed + r)
            t0 = time.perf_counter()
            sel = selector.select(estimate, traj.configurations[0])
            times.append(time.perf_counter() - t0)
            chosen.append(sel.n_anchors)
            evaluations.append(sel.evaluations)
        results.append({"n": n, "s_median": round(statistics.median(times), 4), "s_min": round(min(times), 4),
                        "s_max": round(max(times), 4), "n_a": chosen, "evaluations": evaluations})
        print(f"{n:>5} {statistics.median(times):>9.3f} {min(times):>7.3f} {max(times):>7.3f} {str(chosen):>10} {str(evaluations):>16}")
    if args.json:
        print_json({"results": results, "localizer": args.localizer, "one_core": not args.all_cores})
    return 0
