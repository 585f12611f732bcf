"""``swarm bench runtime``: per-step coordination overhead of the distributed runtime, agent memory and the Zenoh
round trip, with real agent processes on this host (``inchworm.bench.runtime``).

Every process started is stopped by its own pid at the end, on error and on Ctrl-C. Exit
status 3 when agents did not come up or died during the benchmark.
"""

from __future__ import annotations

import argparse
import sys

from inchworm.bench.options import RuntimeBenchOptions
from swarm_cli.entry import EXIT_RUN
from swarm_cli.options import add_json_option, add_localizer_option, add_model_options, model_config, print_result
from swarm_cli.schema import add_fields, options_of


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("runtime", help="per-step coordination overhead with 10 and 50 agent processes, agent memory, Zenoh RTT")
    add_fields(p, RuntimeBenchOptions, exclude=("localizer", "model"))
    add_localizer_option(p)
    add_model_options(p)
    add_json_option(p)
    p.set_defaults(run=run)


def options(args: argparse.Namespace) -> RuntimeBenchOptions:
    """The benchmark the flags ask for."""
    return options_of(args, RuntimeBenchOptions, localizer=args.localizer, model=model_config(args))


def run(args: argparse.Namespace) -> int:
    from coordinator.node.zenoh_backend import AgentError  # noqa: PLC0415
    from inchworm.bench.runtime import bench_runtime  # noqa: PLC0415

    try:
        result = bench_runtime(options(args))
    except AgentError as exc:
        print(f"swarm bench runtime: error: {exc}", file=sys.stderr, flush=True)
        return EXIT_RUN
    return print_result(result, args.json)
