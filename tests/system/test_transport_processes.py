"""The Zenoh layer with child processes, on loopback only: a SIGKILLed child's liveliness token disappears; a router
process drops oversized command payloads and its memory returns."""

from __future__ import annotations

import os
import queue
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import zenoh

from runtime.wire.messages import MAX_MESSAGE_BYTES
from runtime.wire.transport import (
    MAX_WIRE_BYTES,
    ZenohSettings,
    alive_now,
    open_loopback_hub,
    open_session,
    publish,
    subscribe_queue,
    watch_liveliness,
)
from tests.integration.test_transport import _wait_for
from tests.routers import start_router
from tests.waiting import matched_publisher

REPO = Path(__file__).resolve().parents[2]
CHILD = """
import sys, time
from runtime.wire.transport import ZenohSettings, declare_token, open_session, publish
settings, alive_key, data_key = ZenohSettings.from_json(sys.argv[1]), sys.argv[2], sys.argv[3]
with open_session(settings) as session:
    token = declare_token(session, alive_key)
    while True:
        publish(session, data_key, b"hello from the child")
        time.sleep(0.05)
"""


@pytest.fixture
def hub() -> Iterator[tuple[zenoh.Session, ZenohSettings]]:
    """A router session on a free loopback port and the client settings that reach it."""
    session, member, _ = open_loopback_hub()
    with session:
        yield session, member


def test_killed_child_process_loses_its_token(hub) -> None:
    hub_session, member = hub
    events: queue.Queue[tuple[str, bool]] = queue.Queue()
    watch_liveliness(hub_session, "test/alive/*", lambda key, alive: events.put((key, alive)))
    _, inbox = subscribe_queue(hub_session, "test/data/child")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")]))}
    child = subprocess.Popen(
        [sys.executable, "-c", CHILD, member.to_json(), "test/alive/child", "test/data/child"], cwd=REPO, env=env
    )
    try:
        assert inbox.get(timeout=10.0) == ("test/data/child", b"hello from the child")
        _wait_for(events, ("test/alive/child", True))
        assert alive_now(hub_session, "test/alive/*") == {"test/alive/child"}

        os.kill(child.pid, signal.SIGKILL)
        _wait_for(events, ("test/alive/child", False))  # the hub notices the dead connection
        assert child.wait(timeout=10.0) == -signal.SIGKILL
        with pytest.raises(ProcessLookupError):
            os.kill(child.pid, 0)
        assert alive_now(hub_session, "test/alive/*") == set()
    finally:
        if child.poll() is None:
            child.kill()
        child.wait(timeout=5.0)


def _rss_mb(pid: int) -> float:
    return int(Path(f"/proc/{pid}/status").read_text().split("VmRSS:")[1].split()[0]) / 1024


def test_oversized_payloads_on_a_command_key_are_dropped_by_the_router_and_its_memory_returns():
    """Five 20 MB payloads on a command key through `swarm router`: no subscriber receives them (they exceed
    MAX_WIRE_BYTES, which every session and the router configs set), a small message right behind them still
    arrives at once, and the router's resident memory does not keep them."""
    assert MAX_WIRE_BYTES >= MAX_MESSAGE_BYTES
    procs: list[subprocess.Popen] = []
    endpoint = start_router(procs, {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2])})
    router = procs[0]
    try:
        member = ZenohSettings("client", connect=(endpoint,))
        with open_session(member) as forger, open_session(member) as agent:
            _sub, inbox = subscribe_queue(agent, "swarm/flood/robot/3/cmd")
            matched_publisher(forger, "swarm/flood/robot/3/cmd").undeclare()  # the router routes the key to the subscriber
            before = _rss_mb(router.pid)
            for _ in range(5):
                publish(forger, "swarm/flood/robot/3/cmd", bytes(20_000_000))
            publish(forger, "swarm/flood/robot/3/cmd", b"small")
            key, payload = inbox.get(timeout=5)
            assert payload == b"small" and inbox.empty()
            time.sleep(1.0)
            grown = _rss_mb(router.pid) - before
        print(f"router resident memory after 5 x 20 MB on a command key: +{grown:.1f} MB")
        assert grown < 20
    finally:
        router.terminate()
        router.wait(timeout=15)
