"""``swarm bench physics``: how well a plan made with the noise model predicts the physical world (``inchworm.bench.physics``;
docs/physics.md). ``--json``: the last line is ``{"trajectories", "configs", "robots", "method", "rows": [{"world",
"pf_mean", "pf_sd", "e_l_mean", "e_l_planned_mean", "contacts_per_100", "stuck_per_100"}, ...], "pf_ratio"}``."""

from __future__ import annotations

import argparse

from inchworm.bench.options import PhysicsBenchOptions
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
from swarm_cli.schema import add_fields, options_of


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("physics", help="the noise model's prediction against the physical world: P_f, e_l, contacts")
    add_fields(p, PhysicsBenchOptions, exclude=("workers", "run"))
    add_workers_option(p)
    add_localizer_option(p)
    add_selection_options(p)
    add_model_options(p)
    add_json_option(p)
    p.set_defaults(run=run)


def options(args: argparse.Namespace) -> PhysicsBenchOptions:
    """The benchmark the flags ask for (the run's options from the shared groups)."""
    from inchworm.options import RunOptions  # noqa: PLC0415

    return options_of(args, PhysicsBenchOptions, workers=args.workers,
                      run=RunOptions(model=model_config(args), localizer=args.localizer, selection=selection_config(args)))


def run(args: argparse.Namespace) -> int:
    from inchworm.bench.physics import bench_physics  # noqa: PLC0415
    from inchworm.progress import Progress  # noqa: PLC0415

    chosen = options(args)
    return print_result(bench_physics(chosen, Progress(2 * chosen.trajectories, "bench physics")), args.json)
