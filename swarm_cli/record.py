"""``swarm record``: record every message of a run to an MCAP file (runtime.recording.mcap_log, docs/recording.md).

    swarm record --run demo --hub tcp/127.0.0.1:7447 [--out recordings/demo.mcap]

Connects as a Zenoh client to the run's hub, subscribes to ``swarm/<run>/**`` and writes
until SIGINT or SIGTERM, then finishes the file and prints its path and message count.
"Recording ..." on stderr means the subscription is declared (messages published
earlier are not recorded). Exit status 0, 2 on bad input.
"""

from __future__ import annotations

import argparse
import sys

from inchworm.specs import RecorderSpec
from swarm_cli.entry import portable_command, run_standalone
from swarm_cli.options import add_connection_options, connection_of
from swarm_cli.schema import add_fields, options_of


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("record", help="record every message of a run to an MCAP file until Ctrl-C / SIGTERM")
    add_arguments(p)
    p.set_defaults(run=run)


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_fields(p, RecorderSpec, only=("run_id",))
    add_connection_options(p)
    add_fields(p, RecorderSpec, exclude=("run_id",))


def spec_of(args: argparse.Namespace) -> RecorderSpec:
    """The ``RecorderSpec`` of the parsed flags."""
    return options_of(args, RecorderSpec, **connection_of(args), command=portable_command("swarm record", sys.argv[1:]))


def run(args: argparse.Namespace) -> int:
    from inchworm.process_mains import run_recorder  # noqa: PLC0415 - zenoh, mcap when it runs

    return run_recorder(spec_of(args))


def main(argv: list[str] | None = None) -> int:
    return run_standalone("swarm record", add_arguments, run, argv)


if __name__ == "__main__":
    sys.exit(main())
