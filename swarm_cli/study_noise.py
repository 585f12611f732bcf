"""``swarm study noise``: where the online selection chooses anchors and beats ref57; see ``inchworm.studies.noise``."""

from __future__ import annotations

import argparse

from coordinator.localization.registry import DEFAULT_LOCALIZER
from inchworm.studies.noise import NoiseOptions
from swarm_cli.options import add_json_option, add_model_options, add_selection_options, add_study_options, run_options, run_study
from swarm_cli.schema import add_fields, options_of


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("noise", help="sweep motion/sensing noise and localizer: chosen n_a and P_f vs ref57")
    add_fields(p, NoiseOptions, exclude=("run",))
    add_study_options(p, "out/study-noise", "runs.jsonl, runs.csv, noise.png and study.toml")
    add_selection_options(p)
    add_model_options(p)
    add_json_option(p)
    p.set_defaults(run=run, localizer=DEFAULT_LOCALIZER)


def options(args: argparse.Namespace) -> NoiseOptions:
    """The study the flags ask for."""
    return options_of(args, NoiseOptions, run=run_options(args))


def run(args: argparse.Namespace) -> int:
    from inchworm.studies.noise import study_noise  # noqa: PLC0415

    chosen = options(args)
    return run_study(args, study_noise, chosen, len(chosen.tasks()), "study noise")
