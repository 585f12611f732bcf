"""``swarm study selection``: the online anchor search against the exhaustive optimum; see ``inchworm.studies.selection``."""

from __future__ import annotations

import argparse
from pathlib import Path

from swarm_cli.options import add_simulation_options, add_study_options, print_result, run_options, run_study


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("selection", help="online anchor search vs exhaustive optimum, heuristic and random plans")
    p.add_argument("--robots", type=int, default=8, help="n_r (default 8)")
    p.add_argument("--configs", type=int, default=20, help="random configuration changes (default 20)")
    p.add_argument("--screen-samples", type=int, default=32, help="samples per plan to shortlist the exhaustive enumeration (default 32)")
    p.add_argument("--pick-samples", type=int, default=256, help="fresh samples to pick the optimum from the shortlist (default 256)")
    p.add_argument("--eval-samples", type=int, default=512, help="fresh samples every reported plan is evaluated on (default 512)")
    p.add_argument("--seed", type=int, default=0, help="configuration c uses the seed [seed, c] (default 0)")
    add_study_options(p, "out/study-selection", "configs.jsonl, configs.csv, selection.png and study.toml")
    p.add_argument("--no-optimum", action="store_true", help="skip the exhaustive optimum (search against the heuristic only)")
    p.add_argument("--genetic-gain", action="store_true", help="instead: where the forced genetic search beats its seed (docs/selection.md)")
    p.add_argument("--from-csv", type=Path, default=None,
                   help="summarise the rows of an earlier (possibly interrupted) study's configs.csv instead of running")
    add_simulation_options(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from inchworm.studies.selection import SelectionStudyOptions, selection_from_csv, study_selection  # noqa: PLC0415

    if args.genetic_gain:
        from inchworm.studies.genetic_gain import GeneticGainOptions as Gain, study_genetic_gain  # noqa: PLC0415
        return print_result(study_genetic_gain(Gain(args.robots, args.configs, args.eval_samples, args.seed, run_options(args))), args.json)
    options = SelectionStudyOptions(args.robots, args.configs, args.screen_samples, args.pick_samples, args.eval_samples, args.seed,
                                    run_options(args), not args.no_optimum)
    if args.from_csv is None:
        return run_study(args, study_selection, options, options.configs, "study selection", "configs")
    result = selection_from_csv(args.from_csv, options)
    return print_result(result, args.json)
