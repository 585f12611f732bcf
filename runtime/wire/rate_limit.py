"""A token bucket: how often a process answers what anyone may send it (refusals of forged commands)."""

from __future__ import annotations

import threading
import time

from runtime.errors import SwarmInputError


class RateLimit:
    """At most ``burst`` events at once and ``per_s`` per second on average; ``suppressed`` counts the others."""

    def __init__(self, per_s: float, burst: int) -> None:
        if not (per_s > 0 and burst >= 1):
            raise SwarmInputError(f"a rate limit needs per_s > 0 and burst >= 1, got {per_s!r}, {burst!r}")
        self.per_s, self.burst = float(per_s), int(burst)
        self.suppressed = 0
        self._tokens = float(burst)
        self._last = time.monotonic()
        self._lock = threading.Lock()

    def allow(self) -> bool:
        """Whether one more event may happen now (then it is counted as done)."""
        with self._lock:
            now = time.monotonic()
            self._tokens = min(self.burst, self._tokens + (now - self._last) * self.per_s)
            self._last = now
            if self._tokens >= 1.0:
                self._tokens -= 1.0
                return True
            self.suppressed += 1
            return False
