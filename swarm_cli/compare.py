"""``swarm compare``: Table I/II of the paper for every method on the same random trajectories (``inchworm.comparison``).

Runs are spread over the machine's cores; each finished run is kept at once in
``--out/runs.jsonl`` and ``--out/runs.csv``, so ``--resume`` continues an interrupted
comparison to the same result.
"""

from __future__ import annotations

import argparse

from coordinator.strategies import METHODS
from swarm_cli.options import add_simulation_options, add_study_options, names, run_options, run_study


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("compare", help="Table I/II: P_f of every method on the same random trajectories")
    p.add_argument("--robots", type=int, default=10, help="n_r (default 10)")
    p.add_argument("--trajectories", type=int, default=6, help="random trajectories (default 6; the paper: 100)")
    p.add_argument("--configs", type=int, default=8, help="configurations per trajectory n_d (default 8; the paper: 100)")
    p.add_argument("--methods", default=",".join(METHODS), help=f"comma-separated methods (default: all: {','.join(METHODS)})")
    p.add_argument("--seed", type=int, default=0, help="trajectory t uses seed + t (default 0)")
    p.add_argument("--selections", default=None,
                   help="comma-separated anchor rankings to compare for the searching methods, e.g. mc,crlb (default: --selection)")
    add_study_options(p, "out/compare", "runs.jsonl, runs.csv, pf.png and study.toml")
    add_simulation_options(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from inchworm.comparison import CompareOptions, compare  # noqa: PLC0415

    options = CompareOptions(robots=args.robots, trajectories=args.trajectories, configs=args.configs, methods=names(args.methods),
                             seed=args.seed, selections=None if args.selections is None else names(args.selections), run=run_options(args))
    return run_study(args, compare, options, len(options.tasks()), "compare")
