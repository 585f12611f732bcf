"""``swarm bench ...``: benchmarks that print numbers (never timed tests)."""

from __future__ import annotations

import argparse
from collections.abc import Sequence

from swarm_cli.entry import Command, add_commands

NESTED = True
BENCHMARKS = (
    Command("localize", "swarm_cli.bench_localize", "time and accuracy (vs. the Cramer-Rao bound) of one localization step"),
    Command("select", "swarm_cli.bench_select", "time of one full anchor selection for n_r = 10, 30, 100"),
    Command("runtime", "swarm_cli.bench_runtime", "per-step coordination overhead with 10 and 50 agent processes, agent memory, Zenoh RTT"),
    Command("record", "swarm_cli.bench_record", "MCAP recording throughput (msgs/s, MB/s) and its CPU cost per step"),
    Command("gateway", "swarm_cli.bench_gateway", "frame codec throughput, pty round trip, gateway vs simulated step time"),
    Command("collisions", "swarm_cli.bench_collisions", "contacts between robot bodies per method, planned with bodies and as points"),
    Command("envelope", "swarm_cli.bench_envelope", "replay, takeover, NEES, contacts and speed across noise, size, localizer and sensing range"),
    Command("physics", "swarm_cli.bench_physics", "the noise model's prediction against the physical world: P_f, e_l, contacts"),
    Command("faults", "swarm_cli.bench_faults", "lost robots, hostile messages and radio faults: does every run complete, unchanged?"),
    Command("studies", "swarm_cli.bench_studies", "study runs/s and parallel efficiency on the local pool and on Dask (1 and 2 workers)"),
)


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser], argv: Sequence[str] = (), full: bool = False) -> None:
    parser = sub.add_parser("bench", help="benchmarks (print numbers; --json for machines)")
    inner = parser.add_subparsers(dest="benchmark", required=True, metavar="BENCHMARK")
    add_commands(inner, BENCHMARKS, argv, full=full)
