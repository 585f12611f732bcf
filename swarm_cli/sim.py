"""``swarm sim``: one simulated run of a trajectory: a summary, ``configs.csv``, Fig. 13/14/17-style plots and
``trajectory.json``, the trajectory it followed (docs/trajectory.md; ``--trajectory`` runs it again)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from coordinator.strategies import HALF_ANCHORED, METHODS
from inchworm.limits import check_swarm_size
from inchworm.progress import Progress
from runtime.errors import SwarmInputError
from swarm_cli.options import add_simulation_options, add_world_options, model_config, physics_params, print_json, selection_config

LARGE = 1000  # robots: say what is being made before the first progress line


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("sim", help="simulate one run along a trajectory and plot it")
    p.add_argument("--trajectory", type=Path, help="trajectory JSON (docs/trajectory.md); default: a random one")
    p.add_argument("--robots", type=int, default=10, help="robots of the random trajectory (default 10)")
    p.add_argument("--configs", type=int, default=5, help="configurations of the random trajectory (default 5)")
    p.add_argument("--method", choices=METHODS, default="inchworm", help="motion strategy (default inchworm)")
    p.add_argument("--baseline", choices=(*METHODS, "none"), default=None,
                   help="method also run on the same trajectory and noise for errors.png to compare with "
                        "(default ref57, or no-anchors for an odd swarm, which ref57 cannot halve; none: no second run)")
    p.add_argument("--seed", type=int, default=0, help="seed of the trajectory, noise and search (default 0)")
    p.add_argument("--out", type=Path, default=Path("out/sim"), help="folder for the PNG plots (default out/sim)")
    add_simulation_options(p)
    add_world_options(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from inchworm import simulate  # noqa: PLC0415 - scipy and matplotlib when it runs, not for --help
    from inchworm.plots import write_run_plots  # noqa: PLC0415
    from inchworm.runner import write_rows  # noqa: PLC0415
    from inchworm.simulation import (  # noqa: PLC0415
        config_rows,
        config_table,
        contacts_json,
        contacts_text,
        fallback_steps,
        resolve_trajectory,
        world_json,
        world_text,
    )

    cfg, selection = model_config(args), selection_config(args)
    physics = physics_params(args)
    if args.trajectory is None and args.robots >= LARGE:
        print(f"sim: making a random trajectory of {args.robots} robots x {args.configs} configurations", file=sys.stderr, flush=True)
    traj = resolve_trajectory(args.trajectory, args.robots, args.configs, args.seed, cfg)
    if args.trajectory is not None:
        check_swarm_size(traj.n, f"--trajectory {args.trajectory}")
    args.out.mkdir(parents=True, exist_ok=True)
    used = args.out / "trajectory.json"
    traj.save(used)  # what this run followed: swarm sim --trajectory out/sim/trajectory.json runs it again
    kw = dict(model=cfg, localizer=args.localizer, selection=selection, seed=args.seed, world=args.world, physics=physics)
    baseline = args.baseline or ("ref57" if traj.n % 2 == 0 else "no-anchors")
    if baseline in HALF_ANCHORED and traj.n % 2:
        raise SwarmInputError(f"--baseline {baseline} uses n_a = n_r / 2 and needs an even number of robots, got {traj.n}")
    progress = Progress(len(traj.configurations), f"sim {args.method}")
    progress(0)  # a first line at once: a large swarm's first configuration takes a while
    result = simulate(traj, method=args.method, progress=progress, **kw)
    compared = {}
    if baseline not in ("none", args.method):
        compared[baseline] = simulate(traj, method=baseline, progress=Progress(len(traj.configurations), f"sim {baseline}"), **kw)
    plots = write_run_plots(result, args.out, compared)
    rows = config_rows(result)
    print(config_table(result))
    if contacts_text(result, cfg.robot_radius_m):
        print(contacts_text(result, cfg.robot_radius_m))
    if world_text(result):
        print(world_text(result))
    write_rows(args.out / "configs.csv", rows)
    world = ", physical world" if physics else ""
    print(f"P_f = {result.pf():.4f} ({args.method}, {args.localizer} localizer{world}); wrote {used}, {args.out / 'configs.csv'}, "
          f"{', '.join(plots)}")
    if args.json:
        print_json({"method": args.method, "localizer": args.localizer, "seed": args.seed, "pf": result.pf(),
                    "mc_start": selection.mc_start, "mc_emax": selection.mc_emax, "configs": rows,
                    "fallback_steps": len(fallback_steps(result)), "plots": plots,
                    **contacts_json(result, cfg.robot_radius_m), **world_json(result, args.world)})
    return 0
