"""A small progress bar on stderr for long-running commands."""

from __future__ import annotations

import sys
import time


class Progress:
    """``Progress(total, "label")(done)``: redraws in place on a terminal, prints every 10 % otherwise."""

    def __init__(self, total: int, label: str, enabled: bool = True) -> None:
        self.total = max(total, 1)
        self.label = label
        self.enabled = enabled
        self.start = time.monotonic()
        self.tty = sys.stderr.isatty()
        self.last_decile = -1

    def __call__(self, done: int, total: int | None = None) -> None:
        if not self.enabled:
            return
        total = total or self.total
        frac = min(done / max(total, 1), 1.0)
        elapsed = time.monotonic() - self.start
        eta = elapsed / frac - elapsed if frac > 0 else float("nan")
        bar = "#" * int(30 * frac) + "." * (30 - int(30 * frac))
        line = f"{self.label} [{bar}] {done}/{total} {elapsed:5.1f}s (eta {f'{eta:4.0f}' if frac > 0 else '   ?'}s)"
        if self.tty:
            sys.stderr.write("\r" + line + ("\n" if done >= total else ""))
        elif int(10 * frac) > self.last_decile:
            self.last_decile = int(10 * frac)
            sys.stderr.write(line + "\n")
        sys.stderr.flush()
