"""``swarm sim``: one simulated run of a trajectory: a summary, ``configs.csv`` and Fig. 13/14/17-style plots."""

from __future__ import annotations

import argparse
from pathlib import Path

from coordinator.strategies import METHODS
from inchworm.progress import Progress
from swarm_cli.options import add_simulation_options, model_config, print_json, selection_config


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("sim", help="simulate one run along a trajectory and plot it")
    p.add_argument("--trajectory", type=Path, help="trajectory JSON (docs/trajectory.md); default: a random one")
    p.add_argument("--robots", type=int, default=10, help="robots of the random trajectory (default 10)")
    p.add_argument("--configs", type=int, default=5, help="configurations of the random trajectory (default 5)")
    p.add_argument("--method", choices=METHODS, default="inchworm", help="motion strategy (default inchworm)")
    p.add_argument("--baseline", choices=(*METHODS, "none"), default="ref57",
                   help="method also run on the same trajectory and noise for errors.png to compare with (default ref57; none: no second run)")
    p.add_argument("--seed", type=int, default=0, help="seed of the trajectory, noise and search (default 0)")
    p.add_argument("--out", type=Path, default=Path("out/sim"), help="folder for the PNG plots (default out/sim)")
    add_simulation_options(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from inchworm import simulate  # noqa: PLC0415 - scipy and matplotlib when it runs, not for --help
    from inchworm.plots import write_run_plots  # noqa: PLC0415
    from inchworm.runner import write_rows  # noqa: PLC0415
    from inchworm.simulation import config_rows, config_table, fallback_steps, resolve_trajectory  # noqa: PLC0415

    cfg, selection = model_config(args), selection_config(args)
    traj = resolve_trajectory(args.trajectory, args.robots, args.configs, args.seed, cfg)
    kw = dict(model=cfg, localizer=args.localizer, selection=selection, seed=args.seed)
    result = simulate(traj, method=args.method, progress=Progress(len(traj.configurations), f"sim {args.method}"), **kw)
    compared = {}
    if args.baseline not in ("none", args.method):
        compared[args.baseline] = simulate(traj, method=args.baseline, progress=Progress(len(traj.configurations), f"sim {args.baseline}"), **kw)
    plots = write_run_plots(result, args.out, compared)
    rows = config_rows(result)
    print(config_table(result))
    write_rows(args.out / "configs.csv", rows)
    print(f"P_f = {result.pf():.4f} ({args.method}, {args.localizer} localizer); wrote {args.out / 'configs.csv'}, {', '.join(plots)}")
    if args.json:
        print_json({"method": args.method, "localizer": args.localizer, "seed": args.seed, "pf": result.pf(),
                    "configs": rows, "fallback_steps": len(fallback_steps(result)), "plots": plots})
    return 0
