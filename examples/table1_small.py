"""Table I of the paper at a small size: P_f of every method on the same random trajectories (paired).

    python examples/table1_small.py [--robots 6] [--trajectories 4] [--configs 3] [--workers 2] [--out out/example-table1]

Each finished run is kept in OUT/runs.jsonl at once; run again with --resume to continue an
interrupted comparison (the result is the same as without the interruption).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import inchworm
from inchworm.runner import ProcessExecutor


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", type=int, default=6)
    parser.add_argument("--trajectories", type=int, default=4)
    parser.add_argument("--configs", type=int, default=3)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", type=Path, default=Path("out/example-table1"))
    parser.add_argument("--resume", action="store_true")
    args = parser.parse_args()

    options = inchworm.CompareOptions(robots=args.robots, trajectories=args.trajectories, configs=args.configs,
                                      methods=("inchworm", "inchworm-equal-speed", "ref57", "no-anchors"))
    table = inchworm.compare(options, executor=ProcessExecutor(args.workers), out=args.out, resume=args.resume)
    print(table.report())
    ref = table.summary["methods"]["ref57"]["pf_mean"]
    for method, stats in table.summary["methods"].items():
        print(f"{method}: P_f / ref57 = {stats['pf_mean'] / ref:.3f}")
    print("wrote", *table.save(args.out))


if __name__ == "__main__":
    main()
