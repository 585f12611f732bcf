"""``swarm bench ...``: benchmarks that print numbers (never timed tests)."""

from __future__ import annotations

import argparse

from swarm_cli import bench_faults, bench_gateway, bench_localize, bench_record, bench_runtime, bench_select

BENCHMARKS = (bench_localize, bench_select, bench_runtime, bench_record, bench_gateway, bench_faults)


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser("bench", help="benchmarks (print numbers; --json for machines)")
    inner = parser.add_subparsers(dest="benchmark", required=True, metavar="BENCHMARK")
    for module in BENCHMARKS:
        module.register(inner)
