"""What the robot emulator process writes: its event log (JSON lines) and its live gateway config (atomically)."""

from __future__ import annotations

import contextlib
import json
import os
import threading
from pathlib import Path
from typing import Any, TextIO

from runtime.gateway.config import GatewayConfig


class JsonLinesSink:
    """An ``on_event`` callback writing each event as one JSON line, flushed (thread-safe)."""

    def __init__(self, path: Path) -> None:
        self._file: TextIO = open(path, "w", encoding="utf-8")
        self._lock = threading.Lock()

    def __call__(self, event: dict[str, Any]) -> None:
        line = json.dumps(event, separators=(",", ":")) + "\n"
        with self._lock:
            if not self._file.closed:
                self._file.write(line)
                self._file.flush()

    def close(self) -> None:
        with self._lock:
            self._file.close()


def write_atomically(config: GatewayConfig, out: Path) -> None:
    """``config`` to ``out`` via a temporary file and a rename: a reader sees no file or the whole file."""
    tmp = out.with_name(f".{out.name}.{os.getpid()}.tmp")
    try:
        config.save(tmp)
        os.replace(tmp, out)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise
