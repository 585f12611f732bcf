"""Entry point of the ``swarm`` command: subcommands register themselves here."""

from __future__ import annotations

import argparse
import sys

from swarm_cli import (
    agent, bench, certs, compare, coordinator_cmd, emulate, estop, info, launch, link, localize, plot, record, recover, replay, router, sim,
    study,
)
from swarm_cli.entry import guarded

COMMANDS = (sim, compare, study, localize, bench, agent, coordinator_cmd, launch, record, info, recover, replay, plot, link, estop, router, certs,
            emulate)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="swarm", description="Inchworm swarm runtime: simulation, localization, benchmarks.")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for module in COMMANDS:
        module.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return guarded(f"swarm {args.command}", lambda: args.run(args))


if __name__ == "__main__":
    sys.exit(main())
