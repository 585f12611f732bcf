"""``swarm bench record``: MCAP recording throughput and its cost per coordination step (``inchworm.bench.record``)."""

from __future__ import annotations

import argparse

from inchworm.bench.options import RecordBenchOptions
from swarm_cli.entry import library_doc
from swarm_cli.options import add_json_option, print_result
from swarm_cli.schema import add_fields, options_of


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("record", help="MCAP recording throughput (msgs/s, MB/s) and its CPU cost per step",
                       description=library_doc("inchworm.bench.record"), formatter_class=argparse.RawDescriptionHelpFormatter)
    add_fields(p, RecordBenchOptions)
    add_json_option(p)
    p.set_defaults(run=run)


def options(args: argparse.Namespace) -> RecordBenchOptions:
    """The benchmark the flags ask for."""
    return options_of(args, RecordBenchOptions)


def run(args: argparse.Namespace) -> int:
    from inchworm.bench.record import bench_record  # noqa: PLC0415

    result = bench_record(options(args))
    return print_result(result, args.json)
