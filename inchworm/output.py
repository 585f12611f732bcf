"""Reading what a command printed: its machine-readable last line (``--json``)."""

from __future__ import annotations

import json
from typing import Any


def last_json(stdout: str) -> dict[str, Any] | None:
    """What ``print_json`` printed last in a command's output (its last line starting with ``{``), or None."""
    lines = [line for line in stdout.splitlines() if line.startswith("{")]
    try:
        return json.loads(lines[-1]) if lines else None
    except json.JSONDecodeError:
        return None


def print_json(obj: object) -> None:
    """The machine-readable result of a command: one JSON object on one line."""
    print(json.dumps(obj, separators=(",", ":")), flush=True)
