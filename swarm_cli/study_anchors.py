"""``swarm study anchors``: Fig. 4, Fig. 5 (Section 4.1) and Fig. A1 (Appendix A); see ``inchworm.studies.anchors``."""

from __future__ import annotations

import argparse

from swarm_cli.options import add_json_option, add_localizer_option, add_model_options, add_study_options, model_config, run_study


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("anchors", help="Fig. 4 (number of anchors), Fig. 5 (choice of anchors), Appendix A (heuristic vs random)")
    p.add_argument("--robots", type=int, default=10, help="n_r (default 10)")
    p.add_argument("--experiments", type=int, default=60, help="random experiments (default 60; the paper: 1000)")
    p.add_argument("--samples", type=int, default=8, help="Monte Carlo samples per plan per experiment (default 8)")
    p.add_argument("--seed", type=int, default=0, help="experiment e uses the seed [seed, e] (default 0)")
    add_study_options(p, "out/study-anchors", "experiments.jsonl, experiments.csv, the PNG plots and study.toml")
    add_localizer_option(p)
    add_model_options(p)
    add_json_option(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from inchworm.studies.anchors import AnchorsOptions, study_anchors  # noqa: PLC0415

    options = AnchorsOptions(args.robots, args.experiments, args.samples, args.seed, model_config(args), args.localizer)
    if options.note():
        print(options.note())
    return run_study(args, study_anchors, options, options.experiments, "study anchors", "experiments")
