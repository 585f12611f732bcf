"""``swarm bench localize``: time and accuracy of one localization step vs. the Cramer-Rao bound (``inchworm.bench.localize``)."""

from __future__ import annotations

import argparse
import sys

from runtime.errors import SwarmInputError
from swarm_cli.entry import library_doc
from swarm_cli.options import add_json_option, add_model_options, model_config, parse_list, print_result


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser(
        "localize",
        help="time and accuracy (vs. the Cramer-Rao bound) of one localization step",
        description=library_doc("inchworm.bench.localize"),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--sizes", default="10,100,1000", help="comma-separated swarm sizes (default 10,100,1000)")
    parser.add_argument("--trials", type=int, default=5, help="random steps per size (default 5)")
    parser.add_argument("--repeats", type=int, default=5, help="timing repetitions per step (default 5)")
    parser.add_argument("--seed", type=int, default=0, help="trial t uses seed + t (default 0)")
    parser.add_argument("--no-gtsam", action="store_true", help="skip the GTSAM reference even if it is installed")
    parser.add_argument("--still-prior", type=float, default=None, metavar="M",
                        help="prior position std in m of the robots that do not move (anchors); default: the movers' 0.02 m")
    add_model_options(parser)
    add_json_option(parser)
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from inchworm.bench.localize import LocalizeBenchOptions, bench_localize  # noqa: PLC0415

    if args.still_prior is not None and not args.still_prior > 0:
        raise SwarmInputError(f"--still-prior must be > 0 m, got {args.still_prior}")
    options = LocalizeBenchOptions(tuple(parse_list(args.sizes, "--sizes", int, 2)), args.trials, args.repeats, args.seed,
                                   not args.no_gtsam, model_config(args), args.still_prior)
    result = bench_localize(options, lambda text: print(text, file=sys.stderr, flush=True))
    return print_result(result, args.json)
