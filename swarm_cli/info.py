"""``swarm info FILE [--json]``: what an MCAP recording holds (runtime.recording.mcap_log.recording_info).

Channels with their message type, count, first/last time and undecodable messages, the
duration, the run metadata, and whether the file was finished (a killed recorder leaves
it without summary; it is read up to the last complete chunk: see ``swarm recover``).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from runtime.recording.mcap_log import info_text, recording_info
from swarm_cli.options import print_json


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("info", help="channels, counts, duration, metadata and bad messages of an MCAP recording")
    p.add_argument("file", type=Path, help="MCAP file (finished or not)")
    p.add_argument("--json", action="store_true", help="print one JSON object as the last line")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    info = recording_info(args.file)
    print(info_text(info))
    if args.json:
        print_json(info)
    return 0
