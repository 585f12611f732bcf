"""``swarm bench gateway``: the hardware path's costs, measured against emulated robots (``inchworm.bench.gateway``)."""

from __future__ import annotations

import argparse
import sys

from inchworm.bench.options import GatewayBenchOptions
from swarm_cli.entry import library_doc
from swarm_cli.options import add_json_option, add_localizer_option, add_model_options, model_config, print_result
from swarm_cli.schema import add_fields, options_of


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("gateway", help="frame codec throughput, pty round trip, gateway vs simulated step time",
                       description=library_doc("inchworm.bench.gateway"), formatter_class=argparse.RawDescriptionHelpFormatter)
    add_fields(p, GatewayBenchOptions, exclude=("localizer", "model"))
    add_localizer_option(p)
    add_model_options(p)
    add_json_option(p)
    p.set_defaults(run=run)


def options(args: argparse.Namespace) -> GatewayBenchOptions:
    """The benchmark the flags ask for."""
    return options_of(args, GatewayBenchOptions, localizer=args.localizer, model=model_config(args))


def run(args: argparse.Namespace) -> int:
    from inchworm.bench.gateway import bench_gateway  # noqa: PLC0415

    result = bench_gateway(options(args), lambda text: print(f"bench gateway: {text}", file=sys.stderr, flush=True))
    return print_result(result, args.json)
