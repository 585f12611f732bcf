"""``swarm bench faults``: lost robots, hostile messages and radio faults, with real processes on loopback
(``inchworm.bench.faults``; docs/failure-model.md). ``--json``: the last line is
``{"gateway": [...], "lost_robot": {...}, "fuzz": {...}, "coordinator": {...}, "estop_under_flood": {...},
"coordinator_joint": {...}, "rejoin": {...}, "coordinator_stall": {...}}``."""

from __future__ import annotations

import argparse
import sys

from runtime.errors import SwarmInputError
from swarm_cli.options import add_json_option, print_json


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("faults", help="lost robots, hostile messages and radio faults: does every run complete, unchanged?")
    p.add_argument("--seeds", type=int, default=10, help="seeds (runs) per lost-robot and gateway row (default 10)")
    p.add_argument("--fuzz", type=int, default=10_000, help="hostile messages sent during the fuzz run (default 10000)")
    p.add_argument("--flood", type=int, default=3000,
                   help="idle TCP connections held on the TLS router's public listener during the stops (default 3000)")
    p.add_argument("--flood-s", type=float, default=60.0,
                   help="seconds the flood lasts; a stop a second during it and min(FLOOD_S, 60) s after it (default 60)")
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


def run(args: argparse.Namespace) -> int:
    from inchworm.bench.faults import FaultsBenchOptions, bench_faults  # noqa: PLC0415

    options = FaultsBenchOptions(args.seeds, args.fuzz, gateway_rows(args.gateway_rows), args.flood, args.flood_s)
    result = bench_faults(options, lambda text: print(f"bench faults: {text}", file=sys.stderr, flush=True))
    if args.json:
        print_json(result.to_json())
    return 0
