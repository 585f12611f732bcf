"""One simulated run from Python: the paper's method on a random trajectory, its table and its plots.

    python examples/one_run.py [--robots 10] [--configs 5] [--seed 0] [--out out/example-one-run]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import inchworm
from inchworm.plots import plot_errors, plot_trajectory, save_figure
from inchworm.simulation import config_table


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", type=int, default=10)
    parser.add_argument("--configs", type=int, default=5)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("out/example-one-run"))
    args = parser.parse_args()

    run = inchworm.simulate(robots=args.robots, configs=args.configs, seed=args.seed, method="inchworm")
    baseline = inchworm.simulate(run.trajectory, method="ref57", seed=args.seed)  # same trajectory and noise streams
    print(config_table(run))
    print(f"P_f: inchworm {run.pf():.4f}, ref57 {baseline.pf():.4f}")
    save_figure(lambda ax: plot_trajectory(run, ax), args.out / "trajectory.png", (7, 7))
    save_figure(lambda axes: plot_errors({"inchworm": run, "ref57": baseline}, axes), args.out / "errors.png", (11, 4.2), (1, 2))
    print(f"wrote {args.out / 'trajectory.png'} and {args.out / 'errors.png'}")


if __name__ == "__main__":
    main()
