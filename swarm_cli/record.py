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
from pathlib import Path

from inchworm.specs import RecorderSpec
from swarm_cli.entry import portable_command, run_standalone
from swarm_cli.options import add_connection_options


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("record", help="record every message of a run to an MCAP file until Ctrl-C / SIGTERM")
    add_arguments(p)
    p.set_defaults(run=run)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--run", dest="run_id", required=True, help="run id (records swarm/<run>/**)")
    add_connection_options(p)
    p.add_argument("--out", type=Path, default=None, help="MCAP file to write (default recordings/<run>.mcap)")
    p.add_argument("--seed", type=int, default=None, help="seed of the run, stored in the run metadata")
    p.add_argument("--trajectory", type=Path, default=None, help="trajectory JSON of the run, stored in the run metadata")
    p.add_argument("--param", action="append", default=[], metavar="KEY=VALUE",
                   help="extra run metadata (repeatable; VALUE parsed as JSON when it is JSON)")
    p.add_argument("--json", action="store_true", help="print one JSON object as the last line")


def spec_of(args: argparse.Namespace) -> RecorderSpec:
    """The ``RecorderSpec`` of the parsed flags."""
    return RecorderSpec(run_id=args.run_id, hub=args.hub, zenoh_config=args.zenoh_config, out=None if args.out is None else str(args.out),
                        seed=args.seed, trajectory=None if args.trajectory is None else str(args.trajectory), params=tuple(args.param),
                        json=args.json, command=portable_command("swarm record", sys.argv[1:]))


def run(args: argparse.Namespace) -> int:
    from inchworm.process_mains import run_recorder  # noqa: PLC0415 - zenoh, mcap when it runs

    return run_recorder(spec_of(args))


def main(argv: list[str] | None = None) -> int:
    return run_standalone("swarm record", add_arguments, run, argv)


if __name__ == "__main__":
    sys.exit(main())
