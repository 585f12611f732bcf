"""``swarm bench collisions``: contacts between robot bodies per method, planned with bodies and as points
(``inchworm.bench.collisions``; docs/bodies.md). ``--json``: the last line is
``{"radius_m", "trajectories", "configs", "rows": [{"method", "localizer", "bodies", "contacts_per_100",
"configs_with_contact_pct", "steps_per_config", "pf_mean", "noise_scale", "steps_added", "unclear_changes",
"raised_bound_changes", "leg_changes", "staging_stops"}, ...]}``."""

from __future__ import annotations

import argparse

from coordinator.strategies import METHODS
from swarm_cli.options import (
    add_json_option,
    add_model_options,
    add_selection_options,
    add_workers_option,
    model_config,
    names,
    print_result,
    selection_config,
)


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("collisions", help="contacts between robot bodies per method, planned with bodies and as points")
    p.add_argument("--robots", type=int, default=10, help="n_r (default 10)")
    p.add_argument("--trajectories", type=int, default=20, help="random trajectories (default 20)")
    p.add_argument("--configs", type=int, default=20, help="configurations per trajectory (default 20)")
    p.add_argument("--methods", default=",".join(METHODS), help="comma-separated methods (default: all)")
    p.add_argument("--localizers", default="paper", help="comma-separated localizers: paper, joint (default paper)")
    p.add_argument("--seed", type=int, default=0, help="trajectory t uses seed + t (default 0)")
    p.add_argument("--noise-scales", default="1,3,5.58",
                   help="comma-separated factors of the motion noise (turn and drive sigma) run in turn (default 1,3,5.58)")
    add_workers_option(p)
    add_selection_options(p)
    add_model_options(p)
    add_json_option(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from inchworm.bench.collisions import CollisionsBenchOptions, bench_collisions  # noqa: PLC0415
    from inchworm.options import RunOptions  # noqa: PLC0415
    from inchworm.progress import Progress  # noqa: PLC0415
    from runtime.errors import SwarmInputError  # noqa: PLC0415

    try:
        scales = tuple(float(k) for k in names(args.noise_scales))
    except ValueError:
        raise SwarmInputError(f"--noise-scales must list numbers, got {args.noise_scales!r}") from None
    options = CollisionsBenchOptions(args.robots, args.trajectories, args.configs, names(args.methods), names(args.localizers),
                                     args.seed, args.workers, scales, RunOptions(model=model_config(args), selection=selection_config(args)))
    runs = 2 * len(options.methods) * len(options.localizers) * len(scales) * options.trajectories
    return print_result(bench_collisions(options, Progress(runs, "bench collisions")), args.json)
