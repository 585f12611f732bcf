"""``swarm bench runtime``: per-step coordination overhead of the distributed runtime, agent memory and the Zenoh
round trip, with real agent processes on this host (``inchworm.bench.runtime``).

Every process started is stopped by its own pid at the end, on error and on Ctrl-C. Exit
status 3 when agents did not come up or died during the benchmark.
"""

from __future__ import annotations

import argparse
import sys

from swarm_cli.entry import EXIT_RUN
from swarm_cli.options import add_json_option, add_localizer_option, add_model_options, model_config, parse_list, print_result

METHODS = ("no-anchors", "ref57")


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("runtime", help="per-step coordination overhead with 10 and 50 agent processes, agent memory, Zenoh RTT")
    p.add_argument("--agents", default="10,50", help="comma-separated numbers of robot agents (default 10,50)")
    p.add_argument("--agents-per-process", type=int, default=None,
                   help="robot agents hosted by one process (default as swarm launch: 1 up to 50 robots, else up to 50)")
    p.add_argument("--steps", type=int, default=20, help="steps timed per swarm size (default 20)")
    p.add_argument("--method", choices=METHODS, default="no-anchors", help="fixed plan (default no-anchors: all move each step)")
    p.add_argument("--seed", type=int, default=0, help="seed of the trajectory and the noise (default 0)")
    p.add_argument("--rtt-count", type=int, default=200, help="pings of the raw Zenoh round trip (default 200)")
    p.add_argument("--start-timeout", type=float, default=120.0, help="seconds to wait for all agents (default 120)")
    p.add_argument("--step-timeout", type=float, default=10.0, help="seconds to wait for a step's answers (default 10)")
    add_localizer_option(p)
    add_model_options(p)
    add_json_option(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from coordinator.node.zenoh_backend import AgentError  # noqa: PLC0415
    from inchworm.bench.runtime import RuntimeBenchOptions, bench_runtime  # noqa: PLC0415

    options = RuntimeBenchOptions(tuple(parse_list(args.agents, "--agents", int, 2)), args.agents_per_process, args.steps, args.method,
                                  args.seed, args.rtt_count, args.start_timeout, args.step_timeout, args.localizer, model_config(args))
    try:
        result = bench_runtime(options)
    except AgentError as exc:
        print(f"swarm bench runtime: error: {exc}", file=sys.stderr, flush=True)
        return EXIT_RUN
    return print_result(result, args.json)
