"""``swarm sim``: one simulated run of a trajectory: a summary, ``configs.csv``, Fig. 13/14/17-style plots and
``trajectory.json``, the trajectory it followed (docs/trajectory.md; ``--trajectory`` runs it again). Its options are
``inchworm.sim_options.SimOptions`` (flags made from the fields, ``swarm_cli.schema``); ``--baseline`` and ``--out``
are the command's own: what else it runs for ``errors.png`` and where it writes."""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

from coordinator.strategies import HALF_ANCHORED, METHODS
from inchworm.limits import check_swarm_size
from inchworm.progress import Progress
from inchworm.sim_options import SimOptions
from runtime.errors import SwarmInputError
from swarm_cli.options import add_simulation_options, add_world_options, model_config, physics_params, print_json, selection_config
from swarm_cli.schema import add_fields, options_of

LARGE = 1000  # robots: say what is being made before the first progress line
NO_FLAG = ("initial_delta_m", "initial_heading_sigma_rad")  # the start estimate's uncertainty: from Python only


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("sim", help="simulate one run along a trajectory and plot it")
    add_fields(p, SimOptions, only=("trajectory", "robots", "configs", "method"))
    p.add_argument("--baseline", choices=(*METHODS, "none"), default=None,
                   help="method also run on the same trajectory and noise for errors.png to compare with "
                        "(default ref57, or no-anchors for an odd swarm, which ref57 cannot halve; none: no second run)")
    add_fields(p, SimOptions, only=("seed",))
    p.add_argument("--out", type=Path, default=Path("out/sim"), help="folder for the PNG plots (default out/sim)")
    add_simulation_options(p)
    add_world_options(p)
    p.set_defaults(run=run)


def options(args: argparse.Namespace) -> SimOptions:
    """The run the flags ask for (the model, localizer, anchor search and world from the shared groups)."""
    return options_of(args, SimOptions, keep=NO_FLAG, model=model_config(args), localizer=args.localizer, selection=selection_config(args),
                      world=args.world, physics=physics_params(args))


def run(args: argparse.Namespace) -> int:
    from inchworm import simulate  # noqa: PLC0415 - scipy and matplotlib when it runs, not for --help
    from inchworm.plots import write_run_plots  # noqa: PLC0415
    from inchworm.runner import write_rows  # noqa: PLC0415
    from inchworm.simulation import config_rows, config_table, contacts_text, world_text  # noqa: PLC0415

    chosen = options(args)
    cfg, method, localizer = chosen.model, str(chosen.method), str(chosen.localizer)
    if chosen.trajectory is None and chosen.robots >= LARGE:
        print(f"sim: making a random trajectory of {chosen.robots} robots x {chosen.configs} configurations", file=sys.stderr, flush=True)
    traj = chosen.run_trajectory()
    if chosen.trajectory is not None:
        check_swarm_size(traj.n, f"--trajectory {chosen.trajectory}")
    chosen = replace(chosen, trajectory=traj)
    args.out.mkdir(parents=True, exist_ok=True)
    used = args.out / "trajectory.json"
    traj.save(used)  # what this run followed: swarm sim --trajectory out/sim/trajectory.json runs it again
    baseline = args.baseline or ("ref57" if traj.n % 2 == 0 else "no-anchors")
    if baseline in HALF_ANCHORED and traj.n % 2:
        raise SwarmInputError(f"--baseline {baseline} uses n_a = n_r / 2 and needs an even number of robots, got {traj.n}")
    progress = Progress(len(traj.configurations), f"sim {method}")
    progress(0)  # a first line at once: a large swarm's first configuration takes a while
    result = simulate(chosen, progress=progress)
    compared = {}
    if baseline not in ("none", method):
        compared[baseline] = simulate(replace(chosen, method=baseline), progress=Progress(len(traj.configurations), f"sim {baseline}"))
    plots = write_run_plots(result, args.out, compared)
    rows = config_rows(result)
    print(config_table(result))
    if contacts_text(result, cfg.robot_radius_m):
        print(contacts_text(result, cfg.robot_radius_m))
    if world_text(result):
        print(world_text(result))
    write_rows(args.out / "configs.csv", rows)
    world = ", physical world" if chosen.physics else ""
    print(f"P_f = {result.pf():.4f} ({method}, {localizer} localizer{world}); wrote {used}, {args.out / 'configs.csv'}, "
          f"{', '.join(plots)}")
    if args.json:
        print_json(result.to_json(plots))
    return 0
