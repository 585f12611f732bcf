"""``swarm study noise``: where the online selection chooses anchors and beats ref57; see ``inchworm.studies.noise``."""

from __future__ import annotations

import argparse

from coordinator.localization.registry import BUILTIN_LOCALIZERS, DEFAULT_LOCALIZER
from swarm_cli.options import add_json_option, add_model_options, add_selection_options, add_study_options, names, parse_list, run_options, run_study


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("noise", help="sweep motion/sensing noise and localizer: chosen n_a and P_f vs ref57")
    p.add_argument("--motion-scales", default="0.5,1,2,4", help="factors on turn and drive sigmas (default 0.5,1,2,4)")
    p.add_argument("--sensing-scales", default="0.25,1,4", help="factors on range and bearing sigmas (default 0.25,1,4)")
    p.add_argument("--localizers", default=",".join(BUILTIN_LOCALIZERS),
                   help=f"localizers to sweep, any registered one (default {','.join(BUILTIN_LOCALIZERS)})")
    p.add_argument("--robots", type=int, default=10, help="robots per trajectory (default 10)")
    p.add_argument("--trajectories", type=int, default=3, help="random trajectories per setting (default 3)")
    p.add_argument("--configs", type=int, default=4, help="configurations per trajectory (default 4)")
    p.add_argument("--seed", type=int, default=0, help="seed of the trajectories and noise (default 0)")
    add_study_options(p, "out/study-noise", "runs.jsonl, runs.csv, noise.png and study.toml")
    add_selection_options(p)
    add_model_options(p)
    add_json_option(p)
    p.set_defaults(run=run, localizer=DEFAULT_LOCALIZER)


def run(args: argparse.Namespace) -> int:
    from inchworm.studies.noise import NoiseOptions, study_noise  # noqa: PLC0415

    options = NoiseOptions(tuple(parse_list(args.motion_scales, "--motion-scales", float)),
                           tuple(parse_list(args.sensing_scales, "--sensing-scales", float)),
                           names(args.localizers), args.robots, args.trajectories, args.configs, args.seed, run_options(args))
    return run_study(args, study_noise, options, len(options.tasks()), "study noise")
