"""``swarm bench select``: wall time of one full anchor selection for n_r = 10, 30, 100 (``inchworm.bench.select``)."""

from __future__ import annotations

import argparse
import sys

from swarm_cli.options import add_simulation_options, parse_list, print_result, run_options


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("select", help="time of one full anchor selection for n_r = 10, 30, 100")
    p.add_argument("--sizes", default="10,30,100", help="comma-separated swarm sizes (default 10,30,100)")
    p.add_argument("--repeats", type=int, default=3, help="selections per size, each on a new random step (default 3)")
    p.add_argument("--seed", type=int, default=0, help="seed of the random steps (default 0)")
    p.add_argument("--all-cores", action="store_true", help="do not pin the process to one core")
    p.add_argument("--search-all", action="store_true", help="search every count (no outer-loop bound), to time searched selections")
    add_simulation_options(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from inchworm.bench.select import SelectBenchOptions, bench_select  # noqa: PLC0415

    options = SelectBenchOptions(tuple(parse_list(args.sizes, "--sizes", int, 2)), args.repeats, args.seed, not args.all_cores, run_options(args),
                                 args.search_all)
    result = bench_select(options, lambda text: print(text, file=sys.stderr, flush=True))
    return print_result(result, args.json)
