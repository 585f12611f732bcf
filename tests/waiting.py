"""Polling until a condition holds, for tests that watch other processes, and a publisher that waits for its subscriber."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import TypeVar

import zenoh

T = TypeVar("T")


def wait_for(predicate: Callable[[], T], timeout_s: float, what: str) -> T:
    """The first truthy value of ``predicate()`` (polled every 20 ms); fails the test naming ``what`` after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while not (value := predicate()):
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.02)
    return value


def matched_publisher(session: zenoh.Session, key: str, timeout_s: float = 10.0) -> zenoh.Publisher:
    """A publisher on ``key`` once a subscriber matches it (the subscription has propagated): an event, not a sleep."""
    publisher = session.declare_publisher(key)
    matched = threading.Event()
    listener = publisher.declare_matching_listener(lambda status: matched.set() if status.matching else None)
    try:
        assert publisher.matching_status.matching or matched.wait(timeout_s), f"no subscriber matched {key} within {timeout_s} s"
    finally:
        listener.undeclare()
    return publisher
