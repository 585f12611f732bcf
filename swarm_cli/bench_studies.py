"""``swarm bench studies``: runs/s of a small compare on the local pool and on Dask, 1 and 2 workers (``inchworm.bench.studies``)."""

from __future__ import annotations

import argparse
import sys

from swarm_cli.options import add_json_option, print_result


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    add_json_option(p := sub.add_parser("studies", help="study runs/s and parallel efficiency on the local pool and on Dask (1 and 2 workers)"))
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from inchworm.bench.studies import bench_studies  # noqa: PLC0415

    return print_result(bench_studies(say=lambda text: print(text, file=sys.stderr, flush=True)), args.json)
