"""``swarm bench collisions``: contacts between robot bodies per method, planned with bodies and as points
(``inchworm.bench.collisions``; docs/bodies.md). ``--json``: the last line is
``{"radius_m", "trajectories", "configs", "rows": [{"method", "localizer", "bodies", "contacts_per_100",
"configs_with_contact_pct", "steps_per_config", "pf_mean", "noise_scale", "steps_added", "unclear_changes",
"raised_bound_changes", "leg_changes", "staging_stops"}, ...]}``."""

from __future__ import annotations

import argparse

from inchworm.bench.options import CollisionsBenchOptions
from inchworm.options import RunOptions
from swarm_cli.options import (
    add_json_option,
    add_model_options,
    add_selection_options,
    add_workers_option,
    model_config,
    print_result,
    selection_config,
)
from swarm_cli.schema import add_fields, options_of


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("collisions", help="contacts between robot bodies per method, planned with bodies and as points")
    add_fields(p, CollisionsBenchOptions, exclude=("workers", "run"))
    add_workers_option(p)
    add_selection_options(p)
    add_model_options(p)
    add_json_option(p)
    p.set_defaults(run=run)


def options(args: argparse.Namespace) -> CollisionsBenchOptions:
    """The benchmark the flags ask for."""
    return options_of(args, CollisionsBenchOptions, workers=args.workers,
                      run=RunOptions(model=model_config(args), selection=selection_config(args)))


def run(args: argparse.Namespace) -> int:
    from inchworm.bench.collisions import bench_collisions  # noqa: PLC0415
    from inchworm.progress import Progress  # noqa: PLC0415

    o = options(args)
    runs = 2 * len(o.methods) * len(o.localizers) * len(o.noise_scales) * o.trajectories
    return print_result(bench_collisions(o, Progress(runs, "bench collisions")), args.json)
