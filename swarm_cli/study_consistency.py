"""``swarm study consistency``: NEES of the reported position covariance along trajectories; see ``inchworm.studies.consistency``."""

from __future__ import annotations

import argparse

from inchworm.studies.consistency import ConsistencyOptions
from swarm_cli.options import add_json_option, add_model_options, add_selection_options, add_study_options, model_config, run_study, selection_config
from swarm_cli.schema import add_fields, options_of


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("consistency", help="NEES of the reported position covariance along trajectories, per localizer and method")
    add_fields(p, ConsistencyOptions, exclude=("model", "selection"))
    add_study_options(p, "out/study-consistency", "runs.jsonl, runs.csv, consistency.png and study.toml")
    add_selection_options(p)
    add_model_options(p)
    add_json_option(p)
    p.set_defaults(run=run)


def options(args: argparse.Namespace) -> ConsistencyOptions:
    """The study the flags ask for."""
    return options_of(args, ConsistencyOptions, model=model_config(args), selection=selection_config(args))


def run(args: argparse.Namespace) -> int:
    from inchworm.studies.consistency import study_consistency  # noqa: PLC0415

    chosen = options(args)
    return run_study(args, study_consistency, chosen, len(chosen.tasks()), "study consistency")
