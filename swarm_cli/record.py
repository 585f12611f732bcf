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
import threading
from pathlib import Path

from runtime.recording.mcap_log import counts_text, record_run, run_metadata
from runtime.wire.keys import run_wildcard, validate_run
from swarm_cli.entry import on_stop_signals, portable_command, run_standalone
from swarm_cli.options import add_connection_options, connection_label, connection_settings, print_json


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


def run(args: argparse.Namespace) -> int:
    validate_run(args.run_id)
    settings = connection_settings(args)
    assert settings is not None, "add_connection_options(p): required"
    out = args.out or Path("recordings") / f"{args.run_id}.mcap"
    meta = run_metadata(connection_label(args), portable_command("swarm record", sys.argv[1:]), args.seed, args.trajectory, args.param)
    stop = threading.Event()
    on_stop_signals(stop.set)
    ready = lambda rec: print(f"swarm record: recording {run_wildcard(args.run_id)} from {connection_label(args)} to {rec.path}",  # noqa: E731
                              file=sys.stderr, flush=True)
    result = record_run(settings, args.run_id, out, meta, stop, on_ready=ready)
    print(f"wrote {result['path']}: {counts_text(result)}"
          + (f" ({result['undecodable']} undecodable)" if result["undecodable"] else ""), flush=True)
    if args.json:
        print_json(result)
    return 0


def main(argv: list[str] | None = None) -> int:
    return run_standalone("swarm record", add_arguments, run, argv)


if __name__ == "__main__":
    sys.exit(main())
