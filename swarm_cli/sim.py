"""``swarm sim``: one simulated run of a trajectory: a summary, ``configs.csv`` and Fig. 13/14/17-style plots."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from coordinator.strategies import METHODS
from runtime.models.trajectory import Trajectory, body_spacing, random_trajectory
from swarm_cli.options import add_simulation_options, model_config, print_json, selection_config
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
    from coordinator.simulate import simulate  # noqa: PLC0415 - scipy and matplotlib when it runs, not for --help
    from swarm_cli.summary import print_config_table, print_contacts, write_csv, write_plots  # noqa: PLC0415

    cfg = model_config(args)
    if args.trajectory:
        traj = Trajectory.load(args.trajectory)
    else:
        traj = random_trajectory(args.robots, args.configs, np.random.default_rng(args.seed), sensing_range=cfg.sensing_range_m, **body_spacing(cfg))
    progress = Progress(len(traj.configurations), f"sim {args.method}")
    result = simulate(traj, args.method, cfg, localizer=args.localizer, selection=selection_config(args), seed=args.seed, progress=progress)
    plots = write_plots(result, args.out)
    rows, fallbacks = print_config_table(result)
    bodies = print_contacts(result, cfg.robot_radius_m)
    write_csv(args.out / "configs.csv", rows)
    print(f"P_f = {result.pf():.4f} ({args.method}, {args.localizer} localizer); wrote {args.out / 'configs.csv'}, {', '.join(plots)}")
    if args.json:
        print_json({"method": args.method, "localizer": args.localizer, "seed": args.seed, "pf": result.pf(),
                    "configs": rows, "fallback_steps": len(fallbacks), "plots": plots, **bodies})
    return 0
