"""``swarm bench record``: MCAP recording throughput and its cost per coordination step (``inchworm.bench.record``)."""

from __future__ import annotations

import argparse

from swarm_cli.entry import library_doc
from swarm_cli.options import add_json_option, parse_list, print_result


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("record", help="MCAP recording throughput (msgs/s, MB/s) and its CPU cost per step",
                       description=library_doc("inchworm.bench.record"), formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--robots", default="10,50", help="comma-separated swarm sizes (default 10,50)")
    p.add_argument("--steps", type=int, default=40, help="steps of messages recorded per run (default 40)")
    p.add_argument("--steps-per-config", type=int, default=4, help="steps per configuration: one PlanMessage each (default 4)")
    p.add_argument("--repeats", type=int, default=3, help="recordings per size and mode, median reported (default 3)")
    p.add_argument("--step-ms", default="20,100",
                   help="coordination time of one step without recording, ms: one value or one per size "
                        "(default 20,100: the runtime's targets for 10 and 50 agents)")
    p.add_argument("--seed", type=int, default=0, help="seed of the positions and measurements (default 0)")
    add_json_option(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from inchworm.bench.record import RecordBenchOptions, bench_record  # noqa: PLC0415

    options = RecordBenchOptions(tuple(parse_list(args.robots, "--robots", int, 1)), args.steps, args.steps_per_config, args.repeats,
                                 tuple(parse_list(args.step_ms, "--step-ms", float, 0)), args.seed)
    result = bench_record(options)
    return print_result(result, args.json)
