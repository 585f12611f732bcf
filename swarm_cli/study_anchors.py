"""``swarm study anchors``: Fig. 4, Fig. 5 (Section 4.1) and Fig. A1 (Appendix A); see ``inchworm.studies.anchors``."""

from __future__ import annotations

import argparse

from inchworm.studies.anchors import AnchorsOptions
from swarm_cli.options import add_json_option, add_localizer_option, add_model_options, add_study_options, model_config, run_study
from swarm_cli.schema import add_fields, options_of


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("anchors", help="Fig. 4 (number of anchors), Fig. 5 (choice of anchors), Appendix A (heuristic vs random)")
    add_fields(p, AnchorsOptions, exclude=("model", "localizer"))
    add_study_options(p, "out/study-anchors", "experiments.jsonl, experiments.csv, the PNG plots and study.toml")
    add_localizer_option(p)
    add_model_options(p)
    add_json_option(p)
    p.set_defaults(run=run)


def options(args: argparse.Namespace) -> AnchorsOptions:
    """The study the flags ask for."""
    return options_of(args, AnchorsOptions, model=model_config(args), localizer=args.localizer)


def run(args: argparse.Namespace) -> int:
    from inchworm.studies.anchors import study_anchors  # noqa: PLC0415

    chosen = options(args)
    if chosen.note():
        print(chosen.note())
    return run_study(args, study_anchors, chosen, chosen.experiments, "study anchors", "experiments")
