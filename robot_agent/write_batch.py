"""Frames written in one system call per batch of work, on the thread that does the batch.

A write to a serial port or pty costs a system call and, on the other side, a wake-up of
the reader (for a pty also a kernel worker's). A thread that handles several frames in a row
(the link's engine draining its queue, a reader answering every frame of one read) collects
what it writes and puts it on the wire at once when the batch ends; writes from any other
thread, or outside a batch, go out at once as before. The bytes and their order on this
thread are unchanged: frames are self-delimiting, so the robot or the link decodes the same
frames from one write as from many.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager


class WriteBatch:
    """``write`` now, or, inside ``collect()`` on the same thread, at the end of the batch."""

    def __init__(self, write: Callable[[bytes], None]) -> None:
        self._write = write
        self._local = threading.local()

    def write(self, data: bytes) -> None:
        pending = getattr(self._local, "pending", None)
        if pending is None:
            self._write(data)
        else:
            pending.append(data)

    @contextmanager
    def collect(self) -> Iterator[None]:
        """Collect this thread's writes until the block ends, then write them as one (nested: the outer block writes)."""
        if getattr(self._local, "pending", None) is not None:
            yield
            return
        pending: list[bytes] = []
        self._local.pending = pending
        try:
            yield
        finally:
            self._local.pending = None
            if pending:
                self._write(pending[0] if len(pending) == 1 else b"".join(pending))
