"""``swarm recover FILE [OUT]``: rewrite an unfinished (killed) MCAP recording as a finished, indexed one.

Keeps the schemas, channels, metadata and every message of the complete chunks (bytes
and times unchanged). OUT defaults to FILE with ``.recovered.mcap``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from runtime.recording.mcap_log import recover
from swarm_cli.options import print_json


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("recover", help="rewrite an unfinished MCAP recording as a finished, indexed file")
    p.add_argument("file", type=Path, help="MCAP file (typically of a killed recorder)")
    p.add_argument("out", type=Path, nargs="?", default=None, help="output file (default FILE.recovered.mcap)")
    p.add_argument("--json", action="store_true", help="print one JSON object as the last line")
    p.set_defaults(run=run)


def default_output(path: Path) -> Path:
    stem = path.name[: -len(".mcap")] if path.name.endswith(".mcap") else path.name
    return path.with_name(stem + ".recovered.mcap")


def run(args: argparse.Namespace) -> int:
    out = args.out or default_output(args.file)
    result = recover(args.file, out)
    state = "finished" if result["source_complete"] else f"unfinished, {result['dropped_bytes']} bytes of an incomplete record dropped"
    print(f"read {result['source']} ({state})")
    print(f"wrote {result['path']}: {result['messages']} messages on {result['channels']} channels, "
          f"{result['schemas']} schemas, {result['metadata']} metadata records")
    if args.json:
        print_json(result)
    return 0
