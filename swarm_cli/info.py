"""``swarm info FILE [--json]``: what an MCAP recording holds (runtime.recording.mcap_log.recording_info).

Channels with their message type, count, first/last time and undecodable messages, the
duration, the run metadata, and whether the file was finished (a killed recorder leaves
it without summary; it is read up to the last complete chunk: see ``swarm recover``).
"""

from __future__ import annotations

import argparse
import json
from datetime import UTC, datetime
from pathlib import Path

from runtime.recording.mcap_log import counts_text, recording_info
from swarm_cli.options import print_json


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("info", help="channels, counts, duration, metadata and bad messages of an MCAP recording")
    p.add_argument("file", type=Path, help="MCAP file (finished or not)")
    p.add_argument("--json", action="store_true", help="print one JSON object as the last line")
    p.set_defaults(run=run)


def _time(ns: int | None) -> str:
    if ns is None:
        return "-"
    return datetime.fromtimestamp(ns / 1e9, UTC).strftime("%Y-%m-%d %H:%M:%S.%f")[:-3] + " UTC"


def run(args: argparse.Namespace) -> int:
    info = recording_info(args.file)
    state = "finished, indexed" if info["indexed"] else "finished, no index" if info["complete"] else "UNFINISHED"
    print(f"file:      {info['path']} ({info['bytes']} bytes, {state})")
    if not info["complete"]:
        lost = info["bytes"] - info["readable_bytes"]
        print(f"           read up to byte {info['readable_bytes']} ({lost} bytes of an incomplete record dropped): {info['problem']}")
        print(f"           'swarm recover {info['path']}' writes a finished copy")
    print(f"messages:  {counts_text(info)}, {info['undecodable']} undecodable")
    print(f"start:     {_time(info['first_ns'])}")
    print(f"end:       {_time(info['last_ns'])}")
    print(f"duration:  {info['duration_s']:.3f} s")
    if info["channels"]:
        width = max(len(c["topic"]) for c in info["channels"])
        tw = max(18, *(len(c["type"] or "") for c in info["channels"]))
        print(f"{'topic':<{width}}  {'type':<{tw}} {'count':>7} {'bad':>5}  {'first (s)':>9} {'last (s)':>9}")
        t0 = info["first_ns"] or 0
        for c in info["channels"]:
            first = "-" if c["first_ns"] is None else f"{(c['first_ns'] - t0) / 1e9:.3f}"
            last = "-" if c["last_ns"] is None else f"{(c['last_ns'] - t0) / 1e9:.3f}"
            bad = "-" if c["type"] is None else str(c["undecodable"])
            reasons = f"  ({', '.join(f'{r}: {n}' for r, n in sorted(c['reasons'].items()))})" if c["reasons"] else ""
            print(f"{c['topic']:<{width}}  {c['type'] or '(no schema)':<{tw}} {c['messages']:>7} {bad:>5}  {first:>9} {last:>9}{reasons}")
    for name, values in info["metadata"].items():
        print(f"metadata {name}:")
        for key, value in values.items():
            text = value if isinstance(value, str) else json.dumps(value, sort_keys=True)
            print(f"  {key}: {text if len(text) <= 200 else text[:197] + '...'}")
    if args.json:
        print_json(info)
    return 0
