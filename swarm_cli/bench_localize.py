"""``swarm bench localize``: time and accuracy of one localization step vs. the Cramer-Rao bound (``inchworm.bench.localize``)."""

from __future__ import annotations

import argparse
import sys

from inchworm.bench.options import LocalizeBenchOptions
from swarm_cli.entry import library_doc
from swarm_cli.options import add_json_option, add_model_options, model_config, print_result
from swarm_cli.schema import add_fields, options_of


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser(
        "localize",
        help="time and accuracy (vs. the Cramer-Rao bound) of one localization step",
        description=library_doc("inchworm.bench.localize"),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_fields(parser, LocalizeBenchOptions, exclude=("model",))
    add_model_options(parser)
    add_json_option(parser)
    parser.set_defaults(run=run)


def options(args: argparse.Namespace) -> LocalizeBenchOptions:
    """The benchmark the flags ask for."""
    return options_of(args, LocalizeBenchOptions, model=model_config(args))


def run(args: argparse.Namespace) -> int:
    from inchworm.bench.localize import bench_localize  # noqa: PLC0415

    result = bench_localize(options(args), lambda text: print(text, file=sys.stderr, flush=True))
    return print_result(result, args.json)
