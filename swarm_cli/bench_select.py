"""``swarm bench select``: wall time of one full anchor selection for n_r = 10, 30, 100 (``inchworm.bench.select``)."""

from __future__ import annotations

import argparse
import sys

from inchworm.bench.options import SelectBenchOptions
from swarm_cli.options import add_simulation_options, print_result, run_options
from swarm_cli.schema import add_fields, options_of


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("select", help="time of one full anchor selection for n_r = 10, 30, 100")
    add_fields(p, SelectBenchOptions, only=("sizes", "repeats", "seed"))
    p.add_argument("--all-cores", action="store_true", help="do not pin the process to one core")
    add_fields(p, SelectBenchOptions, only=("search_all",))
    add_simulation_options(p)
    p.set_defaults(run=run)


def options(args: argparse.Namespace) -> SelectBenchOptions:
    """The benchmark the flags ask for."""
    return options_of(args, SelectBenchOptions, one_core=not args.all_cores, run=run_options(args))


def run(args: argparse.Namespace) -> int:
    from inchworm.bench.select import bench_select  # noqa: PLC0415

    result = bench_select(options(args), lambda text: print(text, file=sys.stderr, flush=True))
    return print_result(result, args.json)
