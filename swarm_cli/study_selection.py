"""``swarm study selection``: the online anchor search against the exhaustive optimum; see ``inchworm.studies.selection``."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

from inchworm.studies.genetic_gain import GeneticGainOptions
from inchworm.studies.selection import SelectionStudyOptions
from swarm_cli.options import add_simulation_options, add_study_options, print_result, run_options, run_study
from swarm_cli.schema import add_fields, options_of

# --robots, --configs, --eval-samples: not given, each mode's own default (the study's, the genetic gain's: the size and
# evaluation set of docs/selection.md's grid at n_r = 10)
_OWN_DEFAULT = ("robots", "configs", "eval_samples")
_FIELDS = {f.name: f for f in dataclasses.fields(SelectionStudyOptions)}
_GAIN = {f.name: f.default for f in dataclasses.fields(GeneticGainOptions)}


def _own_default(p: argparse.ArgumentParser, name: str, more: str = "") -> None:
    """The flag of field ``name``: not given (None), the study's default or the genetic gain's."""
    f = _FIELDS[name]
    p.add_argument("--" + name.replace("_", "-"), type=int, default=None,
                   help=f"{f.metadata['help']} (default {f.default}; with --genetic-gain {_GAIN[name]}{more})")


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("selection", help="online anchor search vs exhaustive optimum, heuristic and random plans")
    _own_default(p, "robots")
    _own_default(p, "configs")
    add_fields(p, SelectionStudyOptions, only=("screen_samples", "pick_samples"))
    _own_default(p, "eval_samples", ", for 10 robots, scaled by 10/n_r")
    add_fields(p, SelectionStudyOptions, only=("seed",))
    add_study_options(p, "out/study-selection", "configs.jsonl, configs.csv, selection.png and study.toml")
    add_fields(p, SelectionStudyOptions, only=("optimum",))
    p.add_argument("--genetic-gain", action="store_true", help="instead: where the forced genetic search beats its seed (docs/selection.md)")
    p.add_argument("--from-csv", type=Path, default=None,
                   help="summarise the rows of an earlier (possibly interrupted) study's configs.csv instead of running")
    add_simulation_options(p)
    p.set_defaults(run=run)


def options(args: argparse.Namespace) -> SelectionStudyOptions:
    """The study the flags ask for (its own robots, configurations and evaluation samples unless given)."""
    return options_of(args, SelectionStudyOptions, keep=[n for n in _OWN_DEFAULT if getattr(args, n) is None], run=run_options(args))


def gain_options(args: argparse.Namespace) -> GeneticGainOptions:
    """The genetic gain the flags ask for (``--genetic-gain``): its own robots, configurations and evaluation samples
    unless given."""
    given = {n: getattr(args, n) for n in _OWN_DEFAULT if getattr(args, n) is not None}
    return GeneticGainOptions(seed=args.seed, run=run_options(args), **given)


def run(args: argparse.Namespace) -> int:
    from inchworm.studies.selection import selection_from_csv, study_selection  # noqa: PLC0415

    if args.genetic_gain:
        from inchworm.studies.genetic_gain import study_genetic_gain  # noqa: PLC0415
        return print_result(study_genetic_gain(gain_options(args)), args.json)
    chosen = options(args)
    if args.from_csv is None:
        for name in _OWN_DEFAULT:  # study.toml records the size and evaluation set the study used
            setattr(args, name, getattr(chosen, name))
        return run_study(args, study_selection, chosen, chosen.configs, "study selection", "configs")
    return print_result(selection_from_csv(args.from_csv, chosen), args.json)
