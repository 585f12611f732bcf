"""``swarm bench faults``: lost robots, hostile messages and radio faults, with real processes on loopback
(``inchworm.bench.faults``; docs/failure-model.md). ``--json``: the last line is
``{"gateway": [...], "lost_robot": {...}, "fuzz": {...}, "coordinator": {...}, "estop_under_flood": {...},
"coordinator_joint": {...}, "rejoin": {...}, "coordinator_stall": {...}}``."""

from __future__ import annotations

import argparse
import sys

from inchworm.bench.options import FaultsBenchOptions
from runtime.errors import SwarmInputError
from swarm_cli.options import add_json_option, print_json
from swarm_cli.schema import add_fields, options_of


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("faults", help="lost robots, hostile messages and radio faults: does every run complete, unchanged?")
    add_fields(p, FaultsBenchOptions, exclude=("gateway_rows",))
    p.add_argument("--gateway-rows", default="0.05,0.05,0.05;0.2,0,0",
                   help="radio faults as 'drop,corrupt,delay_s;...' (default '0.05,0.05,0.05;0.2,0,0'; '' for none)")
    add_json_option(p)
    p.set_defaults(run=run)


def gateway_rows(spec: str) -> tuple[tuple[float, float, float], ...]:
    rows = []
    for part in filter(None, spec.split(";")):
        try:
            drop, corrupt, delay = (float(v) for v in part.split(","))
        except ValueError:
            raise SwarmInputError(f"--gateway-rows {part!r}: expected drop,corrupt,delay_s (e.g. 0.05,0.05,0.05)") from None
        rows.append((drop, corrupt, delay))
    return tuple(rows)


def options(args: argparse.Namespace) -> FaultsBenchOptions:
    """The benchmark the flags ask for."""
    return options_of(args, FaultsBenchOptions, gateway_rows=gateway_rows(args.gateway_rows))


def run(args: argparse.Namespace) -> int:
    from inchworm.bench.faults import bench_faults  # noqa: PLC0415

    result = bench_faults(options(args), lambda text: print(f"bench faults: {text}", file=sys.stderr, flush=True))
    if args.json:
        print_json(result.to_json())
    return 0
