"""``swarm bench gateway``: the hardware path's costs, measured against emulated robots (``inchworm.bench.gateway``)."""

from __future__ import annotations

import argparse
import sys

from swarm_cli.entry import library_doc
from swarm_cli.options import add_json_option, add_localizer_option, add_model_options, model_config, print_result


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("gateway", help="frame codec throughput, pty round trip, gateway vs simulated step time",
                       description=library_doc("inchworm.bench.gateway"), formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--robots", type=int, default=10, help="agents of the step-time comparison (default 10)")
    p.add_argument("--steps", type=int, default=60, help="steps timed per driver and round (default 60)")
    p.add_argument("--rounds", type=int, default=2, help="rounds of sim then gateway, steps pooled per driver (default 2)")
    p.add_argument("--frames", type=int, default=200_000, help="frames through the codec (default 200000)")
    p.add_argument("--commands", type=int, default=300, help="commands of the pty round trip (default 300)")
    p.add_argument("--seed", type=int, default=0, help="seed of the trajectory and noise (default 0)")
    add_localizer_option(p)
    add_model_options(p)
    add_json_option(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from inchworm.bench.gateway import GatewayBenchOptions, bench_gateway  # noqa: PLC0415

    options = GatewayBenchOptions(args.robots, args.steps, args.rounds, args.frames, args.commands, args.seed, args.localizer, model_config(args))
    result = bench_gateway(options, lambda text: print(f"bench gateway: {text}", file=sys.stderr, flush=True))
    return print_result(result, args.json)
