"""``swarm sim``: one simulated run of a trajectory: a summary, ``configs.csv`` and Fig. 13/14/17-style plots."""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import numpy as np

from coordinator.simulate import simulate
from coordinator.strategies import METHODS
from runtime.trajectory import Trajectory, random_trajectory
from swarm_cli.options import add_simulation_options, model_config, print_json, selection_config
from swarm_cli.plots import plot_errors, plot_trajectory
from swarm_cli.progress import Progress


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("sim", help="simulate one run along a trajectory and plot it")
    p.add_argument("--trajectory", type=Path, help="trajectory JSON (docs/trajectory.md); default: a random one")
    p.add_argument("--robots", type=int, default=10, help="robots of the random trajectory (default 10)")
    p.add_argument("--configs", type=int, default=5, help="configurations of the random trajectory (default 5)")
    p.add_argument("--method", choices=METHODS, default="inchworm", help="motion strategy (default inchworm)")
    p.add_argument("--seed", type=int, default=0, help="seed of the trajectory, noise and search (default 0)")
    p.add_argument("--out", type=Path, default=Path("out/sim"), help="folder for the PNG plots (default out/sim)")
    add_simulation_options(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    cfg = model_config(args)
    if args.trajectory:
        traj = Trajectory.load(args.trajectory)
    else:
        traj = random_trajectory(args.robots, args.configs, np.random.default_rng(args.seed), sensing_range=cfg.sensing_range_m)
    progress = Progress(len(traj.configurations), f"sim {args.method}")
    result = simulate(traj, args.method, cfg, localizer=args.localizer, selection=selection_config(args), seed=args.seed, progress=progress)
    args.out.mkdir(parents=True, exist_ok=True)
    plots = [str(plot_trajectory(result, args.out / "trajectory.png")), str(plot_errors(result, args.out / "errors.png"))]
    e_l, follow, travelled = result.localization_errors(), result.following_errors(), result.travelled()
    print(f"{'config':>6} {'n_a':>4} {'steps':>5} {'e_l (mm)':>9} {'follow (mm)':>11} {'travelled (m)':>13}")
    rows = []
    for c, rec in enumerate(result.configs):
        print(f"{c + 1:>6} {rec.plan.n_anchors:>4} {rec.plan.n_steps:>5} {e_l[c] * 1e3:>9.2f} {follow[c] * 1e3:>11.2f} {travelled[c]:>13.3f}")
        rows.append({"config": c + 1, "n_a": rec.plan.n_anchors, "steps": rec.plan.n_steps, "e_l": float(e_l[c]),
                     "following_error": float(follow[c]), "travelled": float(travelled[c])})
    with open(args.out / "configs.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    fallbacks = [s for s in result.steps if s.fallback]
    for s in fallbacks:
        print(f"config {s.config + 1} step {s.step + 1}: kept dead reckoning ({s.fallback})")
    print(f"P_f = {result.pf():.4f} ({args.method}, {args.localizer} localizer); wrote {args.out / 'configs.csv'}, {', '.join(plots)}")
    if args.json:
        print_json({"method": args.method, "localizer": args.localizer, "seed": args.seed, "pf": result.pf(),
                    "configs": rows, "fallback_steps": len(fallbacks), "plots": plots})
    return 0
