"""``swarm study consistency``: NEES of the reported position covariance along trajectories; see ``inchworm.studies.consistency``."""

from __future__ import annotations

import argparse

from coordinator.localization.registry import BUILTIN_LOCALIZERS
from swarm_cli.options import (
    add_json_option,
    add_model_options,
    add_selection_options,
    add_study_options,
    model_config,
    names,
    parse_list,
    run_study,
    selection_config,
)

METHODS = ("no-anchors", "ref57", "heuristic-fixed", "one-at-a-time")


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("consistency", help="NEES of the reported position covariance along trajectories, per localizer and method")
    p.add_argument("--localizers", default=",".join(BUILTIN_LOCALIZERS),
                   help=f"comma-separated, any registered localizer (default {','.join(BUILTIN_LOCALIZERS)})")
    p.add_argument("--methods", default=",".join(METHODS), help=f"comma-separated anchor methods (default {','.join(METHODS)})")
    p.add_argument("--robots", type=int, default=10, help="n_r (default 10)")
    p.add_argument("--configs", type=int, default=100, help="configurations per trajectory (default 100)")
    p.add_argument("--trajectories", type=int, default=48,
                   help="random trajectories (default 48: with 16 a consistent filter leaves [0.7, 1.5] at some configuration quite often)")
    p.add_argument("--seed", type=int, default=0, help="seed of the trajectories and the noise (default 0)")
    p.add_argument("--motion-scales", default="1", help="factors on the turn and drive sigmas, one noise setting each (default 1)")
    p.add_argument("--sensing-scales", default="1", help="factors on the range and bearing sigmas, crossed with --motion-scales (default 1)")
    add_study_options(p, "out/study-consistency", "runs.jsonl, runs.csv, consistency.png and study.toml")
    add_selection_options(p)
    add_model_options(p)
    add_json_option(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from inchworm.studies.consistency import ConsistencyOptions, study_consistency  # noqa: PLC0415

    options = ConsistencyOptions(names(args.localizers), names(args.methods), args.robots, args.configs, args.trajectories, args.seed,
                                 model_config(args), selection_config(args),
                                 tuple(parse_list(args.motion_scales, "--motion-scales", float)),
                                 tuple(parse_list(args.sensing_scales, "--sensing-scales", float)))
    return run_study(args, study_consistency, options, len(options.tasks()), "study consistency")
