"""``swarm study calibration``: the noise at which ref57's P_f matches the paper's, and inchworm / ref57 there;
see ``inchworm.studies.calibration``."""

from __future__ import annotations

import argparse

from coordinator.localization.registry import DEFAULT_LOCALIZER
from inchworm.studies.calibration import CalibrationOptions
from swarm_cli.options import add_json_option, add_model_options, add_selection_options, add_study_options, positive_int, run_options, run_study
from swarm_cli.schema import add_fields, options_of


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("calibration", help="noise at which ref57's P_f matches the paper's; inchworm / ref57 there")
    add_fields(p, CalibrationOptions, exclude=("run",), types={"robots": positive_int})
    add_study_options(p, "out/study-calibration", "runs.jsonl, runs.csv, calibration.png and study.toml")
    add_selection_options(p)
    add_model_options(p)
    add_json_option(p)
    p.set_defaults(run=run, localizer=DEFAULT_LOCALIZER)


def options(args: argparse.Namespace) -> CalibrationOptions:
    """The study the flags ask for."""
    return options_of(args, CalibrationOptions, run=run_options(args))


def run(args: argparse.Namespace) -> int:
    from inchworm.studies.calibration import study_calibration  # noqa: PLC0415

    chosen = options(args)
    total = len(chosen.localizers) * len(chosen.sensing_scales) * len(chosen.seeds) * chosen.trajectories * len(chosen.methods)
    return run_study(args, study_calibration, chosen, total, "study calibration")
