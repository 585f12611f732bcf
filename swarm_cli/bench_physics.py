"""``swarm bench physics``: how well a plan made with the noise model predicts the physical world (``inchworm.bench.physics``;
docs/physics.md). ``--json``: the last line is ``{"trajectories", "configs", "robots", "method", "rows": [{"world",
"pf_mean", "pf_sd", "e_l_mean", "e_l_planned_mean", "contacts_per_100", "stuck_per_100"}, ...], "pf_ratio"}``."""

from __future__ import annotations

import argparse

from coordinator.strategies import METHODS
from swarm_cli.options import (
    add_json_option,
    add_localizer_option,
    add_model_options,
    add_selection_options,
    add_workers_option,
    model_config,
    print_result,
    selection_config,
)


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("physics", help="the noise model's prediction against the physical world: P_f, e_l, contacts")
    p.add_argument("--robots", type=int, default=10, help="n_r (default 10)")
    p.add_argument("--trajectories", type=int, default=10, help="random trajectories (default 10)")
    p.add_argument("--configs", type=int, default=10, help="configurations per trajectory (default 10)")
    p.add_argument("--method", choices=METHODS, default="inchworm", help="motion strategy (default inchworm)")
    p.add_argument("--seed", type=int, default=0, help="trajectory t uses seed + t (default 0)")
    p.add_argument("--physics-param", action="append", default=[], metavar="NAME=VALUE",
                   help="a parameter of the physical world (runtime.world.params.PhysicsParams), repeatable")
    add_workers_option(p)
    add_localizer_option(p)
    add_selection_options(p)
    add_model_options(p)
    add_json_option(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from inchworm.bench.physics import PhysicsBenchOptions, bench_physics  # noqa: PLC0415
    from inchworm.options import RunOptions  # noqa: PLC0415
    from inchworm.progress import Progress  # noqa: PLC0415

    options = PhysicsBenchOptions(args.robots, args.trajectories, args.configs, args.method, args.seed, args.workers,
                                  RunOptions(model=model_config(args), localizer=args.localizer, selection=selection_config(args)),
                                  tuple(args.physics_param))
    return print_result(bench_physics(options, Progress(2 * options.trajectories, "bench physics")), args.json)
