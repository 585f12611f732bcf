"""``swarm study calibration``: the noise at which ref57's P_f matches the paper's, and inchworm / ref57 there;
see ``inchworm.studies.calibration``."""

from __future__ import annotations

import argparse

from coordinator.localization.registry import BUILTIN_LOCALIZERS, DEFAULT_LOCALIZER
from swarm_cli.options import (
    add_json_option,
    add_model_options,
    add_selection_options,
    add_study_options,
    names,
    parse_list,
    positive_int,
    run_options,
    run_study,
)

PAPER_REF57_PF = 0.0673  # inchworm.studies.calibration.PAPER_REF57_PF, without importing the study for the parser


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("calibration", help="noise at which ref57's P_f matches the paper's; inchworm / ref57 there")
    p.add_argument("--localizers", default=",".join(BUILTIN_LOCALIZERS),
                   help=f"localizers, any registered one (default {','.join(BUILTIN_LOCALIZERS)})")
    p.add_argument("--sensing-scales", default="1", help="factors on range and bearing sigmas (default 1)")
    p.add_argument("--target", type=float, default=PAPER_REF57_PF, help="ref57 P_f to match (default the paper's 0.0673)")
    p.add_argument("--max-motion-scale", type=float, default=32.0, help="largest factor on turn and drive sigmas tried (default 32)")
    p.add_argument("--calibration-trajectories", type=int, default=12, help="ref57 trajectories per bisection step (default 12)")
    p.add_argument("--iterations", type=int, default=7, help="bisection steps on log(motion scale) (default 7)")
    p.add_argument("--robots", type=positive_int, default=10, help="robots per trajectory (default 10)")
    p.add_argument("--trajectories", type=int, default=30, help="trajectories per seed set (default 30)")
    p.add_argument("--configs", type=int, default=15, help="configurations per trajectory (default 15)")
    p.add_argument("--seeds", default="0,1000", help="seed sets; trajectory t of set s uses seed s + t (default 0,1000)")
    p.add_argument("--methods", default="inchworm,inchworm-equal-speed,ref57",
                   help="comma-separated methods compared with ref57 at the calibrated noise (default inchworm,inchworm-equal-speed,ref57)")
    add_study_options(p, "out/study-calibration", "runs.jsonl, runs.csv, calibration.png and study.toml")
    add_selection_options(p)
    add_model_options(p)
    add_json_option(p)
    p.set_defaults(run=run, localizer=DEFAULT_LOCALIZER)


def run(args: argparse.Namespace) -> int:
    from inchworm.studies.calibration import CalibrationOptions, study_calibration  # noqa: PLC0415

    options = CalibrationOptions(
        localizers=names(args.localizers), sensing_scales=tuple(parse_list(args.sensing_scales, "--sensing-scales", float)),
        target=args.target, max_motion_scale=args.max_motion_scale, calibration_trajectories=args.calibration_trajectories,
        iterations=args.iterations, robots=args.robots, trajectories=args.trajectories, configs=args.configs,
        seeds=tuple(parse_list(args.seeds, "--seeds", int)), methods=names(args.methods), run=run_options(args))
    total = len(options.localizers) * len(options.sensing_scales) * len(options.seeds) * options.trajectories * len(options.methods)
    return run_study(args, study_calibration, options, total, "study calibration")
