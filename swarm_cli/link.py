"""``swarm link``: the link process of one serial/radio port of a gateway PC (docs/gateway-protocol.md).

    swarm link --config /etc/swarm/gateway.json --port radio0 --run lab --hub tcp/127.0.0.1:7447

Opens the port's device (the only process that does), then bridges the agents of the
robots behind it (``LinkRequest`` / ``LinkReply`` over Zenoh) to the robots (frames with
CRC, retransmission, heartbeats), forwards emergency stops and publishes ``LinkStats``.
Runs until SIGTERM/SIGINT; exit 0. ``python -m swarm_cli.link`` is the same command.
"""

from __future__ import annotations

import argparse
import sys

from inchworm.specs import LinkSpec
from swarm_cli.entry import run_standalone
from swarm_cli.options import add_connection_options, connection_of
from swarm_cli.schema import add_fields, options_of


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("link", help="own one serial/radio port of the gateway and bridge its robots to their agents")
    add_arguments(p)
    p.set_defaults(run=run)


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_fields(p, LinkSpec)
    add_connection_options(p)


def run(args: argparse.Namespace) -> int:
    from inchworm.process_mains import run_link  # noqa: PLC0415 - zenoh when it runs

    return run_link(spec_of(args))


def spec_of(args: argparse.Namespace) -> LinkSpec:
    """The link spec of the flags."""
    return options_of(args, LinkSpec, **connection_of(args))


def main(argv: list[str] | None = None) -> int:
    return run_standalone("swarm link", add_arguments, run, argv)


if __name__ == "__main__":
    sys.exit(main())
