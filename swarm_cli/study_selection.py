"""``swarm study selection``: the online anchor search against the exhaustive optimum; see ``inchworm.studies.selection``."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

from inchworm.studies.genetic_gain import GeneticGainOptions
from inchworm.studies.selection import SelectionStudyOptions
from swarm_cli.options import add_simulation_options, add_study_options, print_result, run_options, run_study
from swarm_cli.schema import add_fields, options_of

# --eval-samples: not given, each mode's own default (the study's evaluation set, the genetic gain's: docs/selection.md)
_EVAL = next(f for f in dataclasses.fields(SelectionStudyOptions) if f.name == "eval_samples")


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("selection", help="online anchor search vs exhaustive optimum, heuristic and random plans")
    add_fields(p, SelectionStudyOptions, only=("robots", "configs", "screen_samples", "pick_samples"))
    p.add_argument("--eval-samples", type=int, default=None,
                   help=f"{_EVAL.metadata['help']} (default {_EVAL.default}; with --genetic-gain {GeneticGainOptions.eval_samples}, "
                        "for 10 robots, scaled by 10/n_r)")
    add_fields(p, SelectionStudyOptions, only=("seed",))
    add_study_options(p, "out/study-selection", "configs.jsonl, configs.csv, selection.png and study.toml")
    add_fields(p, SelectionStudyOptions, only=("optimum",))
    p.add_argument("--genetic-gain", action="store_true", help="instead: where the forced genetic search beats its seed (docs/selection.md)")
    p.add_argument("--from-csv", type=Path, default=None,
                   help="summarise the rows of an earlier (possibly interrupted) study's configs.csv instead of running")
    add_simulation_options(p)
    p.set_defaults(run=run)


def options(args: argparse.Namespace) -> SelectionStudyOptions:
    """The study the flags ask for."""
    return options_of(args, SelectionStudyOptions, keep=("eval_samples",) if args.eval_samples is None else (), run=run_options(args))


def gain_options(args: argparse.Namespace) -> GeneticGainOptions:
    """The genetic gain the flags ask for (``--genetic-gain``): its own evaluation samples unless ``--eval-samples`` is given."""
    given = {} if args.eval_samples is None else {"eval_samples": args.eval_samples}
    return GeneticGainOptions(robots=args.robots, configs=args.configs, seed=args.seed, run=run_options(args), **given)


def run(args: argparse.Namespace) -> int:
    from inchworm.studies.selection import selection_from_csv, study_selection  # noqa: PLC0415

    if args.genetic_gain:
        from inchworm.studies.genetic_gain import study_genetic_gain  # noqa: PLC0415
        return print_result(study_genetic_gain(gain_options(args)), args.json)
    chosen = options(args)
    if args.from_csv is None:
        args.eval_samples = chosen.eval_samples  # study.toml records the evaluation set the study used
        return run_study(args, study_selection, chosen, chosen.configs, "study selection", "configs")
    return print_result(selection_from_csv(args.from_csv, chosen), args.json)
