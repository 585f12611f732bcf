"""Stopping a run: stop signals that never interrupt the writing of a file, and the run-wide emergency stop
with the acknowledgements of the agents and links that acted on it."""

from __future__ import annotations

import contextlib
import queue
import signal
import time
from collections.abc import Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from runtime.wire.keys import estop_ack_key, validate_run
from runtime.wire.messages import EmergencyStop, EstopAck, MessageError, decode, encode, message_key
from runtime.wire.transport import publish

if TYPE_CHECKING:
    import zenoh

    from runtime.wire.transport import ZenohSettings

REPEATS = 3
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)  # every one takes the same path: a clean, run-wide stop


class StopRequested(KeyboardInterrupt):
    """A stop signal ended the run; ``signum`` is its number (exit status 128 + ``signum``)."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


class StopSignals:
    """SIGINT, SIGTERM and SIGHUP as a stop request: the first one raises ``StopRequested`` (a
    ``KeyboardInterrupt``: ends the run), later ones are only noted, and inside ``deferred()``
    (finishing a recording, stopping children) every signal is only noted, never an exception in
    the middle of writing a file.

    ``received`` is the first signal number (None if none came). ``restore()`` puts back the
    previous handlers. Main thread only (Python runs signal handlers there).
    """

    SIGNALS = STOP_SIGNALS

    def __init__(self) -> None:
        self.received: int | None = None
        self._deferred = 0
        self._previous = {sig: signal.signal(sig, self._handle) for sig in self.SIGNALS}

    def _handle(self, signum: int, _frame: object) -> None:
        first = self.received is None
        if first:
            self.received = signum
        if first and not self._deferred:
            raise StopRequested(signum)

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


def send_estop(session: zenoh.Session, run_id: str, source: str, reason: str, repeat_s: float = 0.0) -> int:
    """Publish the run's ``EmergencyStop`` (once, then again spread over ``repeat_s``); the number published."""
    return len(publish_estop(session, EmergencyStop(run=run_id, step=0, source=source, reason=reason), repeat_s))


def publish_estop(session: zenoh.Session, msg: EmergencyStop, repeat_s: float = 0.0) -> list[float]:
    """Publish ``msg`` (once, then again spread over ``repeat_s``); the monotonic times it went out."""
    key, payload = message_key(msg), encode(msg)
    count = 1 if repeat_s <= 0 else REPEATS
    times = []
    for i in range(count):
        publish(session, key, payload)
        times.append(time.monotonic())
        if i + 1 < count:
            time.sleep(repeat_s / (count - 1))
    return times


def collect_acks(inbox: queue.Queue[tuple[str, bytes]], stamp_ns: int, until: float, agents: int | None = None) -> dict[tuple[str, str], EstopAck]:
    """The acknowledgements of the stop stamped ``stamp_ns`` arriving (as ``(key, payload)`` in ``inbox``) before
    monotonic time ``until``, by (by, name); sooner once ``agents`` agents acknowledged, if given."""
    acks: dict[tuple[str, str], EstopAck] = {}
    while (left := until - time.monotonic()) > 0 and (agents is None or sum(by == "agent" for by, _ in acks) < agents):
        try:
            key, payload = inbox.get(timeout=left)
        except queue.Empty:
            break
        try:
            ack = decode(payload, EstopAck, key=key)
        except MessageError:
            continue
        if ack.stop_stamp_ns == stamp_ns:
            acks.setdefault((ack.by, ack.name), ack)
    return acks


@dataclass(frozen=True)
class EstopOutcome:
    """Who acknowledged an operator's emergency stop (``swarm estop``): agents by robot id, links by port name."""

    run: str
    published: int  # how many times the stop was published
    agents: list[int]
    links: list[str]
    robots: list[int]  # every robot an agent or link said it stopped

    def to_json(self) -> dict[str, Any]:
        return {"run": self.run, "published": self.published, "agents": self.agents, "links": self.links, "robots": self.robots}


def emergency_stop(settings: ZenohSettings, run_id: str, source: str, reason: str, repeat_s: float, ack_timeout: float) -> EstopOutcome:
    """Publish an ``EmergencyStop`` to ``run_id`` and collect the acknowledgements for ``ack_timeout`` s (after the first publication)."""
    from runtime.wire.transport import open_session, subscribe_queue  # noqa: PLC0415 - zenoh, only when a stop is sent

    validate_run(run_id)
    msg = EmergencyStop(run=run_id, step=0, source=source, reason=reason)
    with open_session(settings) as session:
        _sub, inbox = subscribe_queue(session, estop_ack_key(run_id))  # before the stop: no answer is missed
        times = publish_estop(session, msg, repeat_s)
        acks = collect_acks(inbox, msg.stamp_ns, times[0] + max(ack_timeout, 0.0))
    return EstopOutcome(run_id, len(times), sorted(int(name) for by, name in acks if by == "agent"),
                        sorted(name for by, name in acks if by == "link"), sorted({r for ack in acks.values() for r in ack.robots}))
