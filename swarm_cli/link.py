"""``swarm link``: the link process of one serial/radio port of a gateway PC (docs/gateway-protocol.md).

    swarm link --config /etc/swarm/gateway.json --port radio0 --run lab --hub tcp/127.0.0.1:7447

Opens the port's device (the only process that does), then bridges the agents of the
robots behind it (``LinkRequest`` / ``LinkReply`` over Zenoh) to the robots (frames with
CRC, retransmission, heartbeats), forwards emergency stops and publishes ``LinkStats``.
Runs until SIGTERM/SIGINT; exit 0. ``python -m swarm_cli.link`` is the same command.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import sys
from pathlib import Path

from robot_agent.link import Link
from runtime.gateway.config import GatewayConfig
from runtime.wire.keys import validate_run
from runtime.wire.transport import claim_identities, open_session
from swarm_cli.entry import on_stop_signals, run_standalone
from swarm_cli.options import add_connection_options, connection_settings


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("link", help="own one serial/radio port of the gateway and bridge its robots to their agents")
    add_arguments(p)
    p.set_defaults(run=run)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", type=Path, required=True, help="gateway config JSON (docs/gateway.md)")
    p.add_argument("--port", required=True, help="name of the port in the config to serve")
    p.add_argument("--run", dest="run_id", required=True, help="run id (the key space swarm/<run>/...)")
    add_connection_options(p)


def run(args: argparse.Namespace) -> int:
    logging.basicConfig(level=logging.WARNING, format=f"link {args.port}: %(levelname)s %(message)s", stream=sys.stderr)
    config = GatewayConfig.load(args.config)
    port = config.port(args.port)
    validate_run(args.run_id)
    with open_session(connection_settings(args)) as session:
        claim_identities(session, args.run_id, ports=[port.name])  # before the device is opened: one link per port
        with contextlib.closing(Link.open(session, args.run_id, port, config)) as link:
            on_stop_signals(link.stop)
            print(f"swarm link: port {port.name} on {port.device} ({port.transport}), robots "
                  f"{','.join(map(str, port.robots))}, run {args.run_id}", file=sys.stderr, flush=True)
            status = link.run()
            print(f"swarm link: {link.summary()}", file=sys.stderr, flush=True)
            return status


def main(argv: list[str] | None = None) -> int:
    return run_standalone("swarm link", add_arguments, run, argv)


if __name__ == "__main__":
    sys.exit(main())
