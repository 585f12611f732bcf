"""Entry point of the ``swarm`` command: subcommands register themselves here."""

from __future__ import annotations

import argparse
import sys

from runtime.errors import LocalizationError, SwarmInputError
from swarm_cli import agent, bench, compare, coordinator_cmd, launch, localize, sim, study
from swarm_cli import info, plot, record, recover, replay

COMMANDS = (sim, compare, study, localize, bench, agent, coordinator_cmd, launch, record, info, recover, replay, plot)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="swarm", description="Inchworm swarm runtime: simulation, localization, benchmarks.")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for module in COMMANDS:
        module.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args.run(args) or 0)
    except (SwarmInputError, LocalizationError, OSError) as exc:
        print(f"swarm {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"swarm {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
