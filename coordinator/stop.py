"""Stopping a run: stop signals that never interrupt the writing of a file, and the run-wide emergency stop."""

from __future__ import annotations

import contextlib
import signal
import time
from collections.abc import Iterator

from runtime.wire.messages import EmergencyStop, encode, message_key
from runtime.wire.transport import publish

REPEATS = 3


class StopSignals:
    """SIGINT and SIGTERM as a stop request: the first one raises ``KeyboardInterrupt`` (ends the run),
    later ones are only noted, and inside ``deferred()`` (finishing a recording, stopping children)
    every signal is only noted, never an exception in the middle of writing a file.

    ``received`` is the first signal number (None if none came). ``restore()`` puts back the
    previous handlers. Main thread only (Python runs signal handlers there).
    """

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self) -> None:
        self.received: int | None = None
        self._deferred = 0
        self._previous = {sig: signal.signal(sig, self._handle) for sig in self.SIGNALS}

    def _handle(self, signum: int, _frame: object) -> None:
        first = self.received is None
        if first:
            self.received = signum
        if first and not self._deferred:
            raise KeyboardInterrupt

    @contextlib.contextmanager
    def deferred(self) -> Iterator[None]:
        """Signals arriving in this block are noted, not raised (a stop request is then ``received``)."""
        self._deferred += 1
        try:
            yield
        finally:
            self._deferred -= 1

    def restore(self) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)



def send_estop(session, run_id: str, source: str, reason: str, repeat_s: float = 0.0) -> int:
    """Publish the run's ``EmergencyStop`` (once, then again spread over ``repeat_s``); the number published."""
    msg = EmergencyStop(run=run_id, step=0, source=source, reason=reason)
    key, payload = message_key(msg), encode(msg)
    count = 1 if repeat_s <= 0 else REPEATS
    for i in range(count):
        publish(session, key, payload)
        if i + 1 < count:
            time.sleep(repeat_s / (count - 1))
    return count
