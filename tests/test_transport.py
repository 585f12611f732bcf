"""The Zenoh layer with real sessions, on loopback only (tcp/127.0.0.1, multicast off)."""

from __future__ import annotations

import math
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

from runtime.errors import SwarmInputError
from runtime.transport import (
    ZenohSettings,
    alive_now,
    declare_token,
    free_tcp_port,
    loopback_hub,
    open_session,
    publish,
    round_trip_ms,
    subscribe,
    subscribe_queue,
    watch_liveliness,
)

REPO = Path(__file__).resolve().parent.parent
DEPLOY = REPO / "deploy"

CHILD = """
import sys, time
from runtime.transport import ZenohSettings, declare_token, open_session, publish
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
    hub_settings, member = loopback_hub(free_tcp_port())
    with open_session(hub_settings) as session:
        yield session, member


def _publish_until_received(
    session: zenoh.Session, key: str, payload: bytes, inbox: queue.Queue[tuple[str, bytes]], timeout_s: float = 3.0
) -> tuple[str, bytes]:
    """Publish every 20 ms until the subscription has propagated and ``inbox`` gets a sample."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        publish(session, key, payload)
        try:
            return inbox.get(timeout=0.02)
        except queue.Empty:
            pass
    raise AssertionError(f"nothing arrived on {key} within {timeout_s} s")


def _wait_for(events: queue.Queue[tuple[str, bool]], expected: tuple[str, bool], timeout_s: float) -> float:
    """Seconds until ``expected`` comes out of ``events``; fails after ``timeout_s``."""
    start = time.monotonic()
    while (left := start + timeout_s - time.monotonic()) > 0:
        try:
            if events.get(timeout=left) == expected:
                return time.monotonic() - start
        except queue.Empty:
            break
    raise AssertionError(f"no liveliness event {expected} within {timeout_s} s")


def test_settings_json_round_trip() -> None:
    settings = ZenohSettings(
        "peer",
        listen=["tcp/127.0.0.1:0"],  # lists become tuples
        connect=("tcp/127.0.0.1:7447", "udp/[::1]:7447", "tls/robot-3.local:7447"),
        config_file=str(DEPLOY / "zenoh-single-host.json5"),
    )
    assert settings.listen == ("tcp/127.0.0.1:0",)
    assert ZenohSettings.from_json(settings.to_json()) == settings
    hub, member = loopback_hub(7447)
    assert (hub.mode, hub.listen, hub.multicast_scouting) == ("router", ("tcp/127.0.0.1:7447",), False)
    assert (member.mode, member.connect, member.listen) == ("client", ("tcp/127.0.0.1:7447",), ())
    assert ZenohSettings.from_json(member.to_json()) == member


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda: ZenohSettings("server"), "mode 'server' is invalid"),
        (lambda: ZenohSettings("router", listen=("127.0.0.1:7447",)), "endpoint '127.0.0.1:7447' is invalid"),
        (lambda: ZenohSettings("peer", connect=("http/host:80",)), "endpoint 'http/host:80' is invalid"),
        (lambda: ZenohSettings("peer", connect=("tcp/127.0.0.1",)), "is invalid"),
        (lambda: ZenohSettings("peer", connect=("tcp/127.0.0.1:0",)), r"port 0 is outside \[1, 65535\]"),
        (lambda: ZenohSettings("router", listen=("tcp/127.0.0.1:70000",)), "port 70000 is outside"),
        (lambda: ZenohSettings("router", listen="tcp/127.0.0.1:7447"), "must be a list"),
        (lambda: ZenohSettings("client", listen=("tcp/127.0.0.1:7447",)), "client cannot listen"),
        (lambda: ZenohSettings("client"), "client needs connect endpoints"),
        (lambda: ZenohSettings("router", config_file="/nonexistent/zenoh.json5"), "does not exist"),
        (lambda: ZenohSettings.from_json("{not json"), "not valid JSON"),
        (lambda: ZenohSettings.from_json('{"mode": "peer", "port": 1}'), "must be a JSON object"),
        (lambda: loopback_hub(0), "hub port 0"),
    ],
)
def test_settings_validation(make, message: str) -> None:
    with pytest.raises(SwarmInputError, match=message):
        make()


def test_client_without_hub_fails_to_open() -> None:
    _, member = loopback_hub(free_tcp_port())
    with pytest.raises(ConnectionError, match="cannot open a zenoh client session"):
        open_session(member)


def test_put_on_one_client_reaches_the_other(hub) -> None:
    hub_session, member = hub
    payload = bytes(range(256))
    with open_session(member) as sender, open_session(member) as receiver:
        _, inbox = subscribe_queue(receiver, "test/data/**")
        assert _publish_until_received(sender, "test/data/7", payload, inbox) == ("test/data/7", payload)

        seen: queue.Queue[tuple[str, bytes]] = queue.Queue()
        callback_subscriber = subscribe(hub_session, "test/cb", lambda key, data: seen.put((key, data)))
        assert _publish_until_received(receiver, "test/cb", b"to the hub", seen) == ("test/cb", b"to the hub")
        callback_subscriber.undeclare()

        token = declare_token(sender, "test/alive/sender")
        deadline = time.monotonic() + 2.0
        while not alive_now(hub_session, "test/alive/*") and time.monotonic() < deadline:
            time.sleep(0.01)
        events: queue.Queue[tuple[str, bool]] = queue.Queue()
        watcher = watch_liveliness(receiver, "test/alive/*", lambda key, alive: events.put((key, alive)))
        _wait_for(events, ("test/alive/sender", True), 2.0)  # declared before the watch: history
        token.undeclare()
        _wait_for(events, ("test/alive/sender", False), 2.0)
        assert alive_now(receiver, "test/alive/*", timeout_s=0.5) == set()
        watcher.undeclare()


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
        _wait_for(events, ("test/alive/child", True), 10.0)
        assert alive_now(hub_session, "test/alive/*") == {"test/alive/child"}

        os.kill(child.pid, signal.SIGKILL)
        assert _wait_for(events, ("test/alive/child", False), 2.0) < 2.0
        assert child.wait(timeout=2.0) == -signal.SIGKILL
        with pytest.raises(ProcessLookupError):
            os.kill(child.pid, 0)
        assert alive_now(hub_session, "test/alive/*") == set()
    finally:
        if child.poll() is None:
            child.kill()
        child.wait(timeout=5.0)


def test_round_trip_ms_is_finite_and_positive() -> None:
    hub_settings, member = loopback_hub(free_tcp_port())
    result = round_trip_ms(hub_settings, member, count=50)
    assert result["count"] == 50
    for name in ("median_ms", "p90_ms", "min_ms", "max_ms"):
        assert math.isfinite(result[name]) and result[name] > 0, (name, result)
    assert result["min_ms"] <= result["median_ms"] <= result["p90_ms"] <= result["max_ms"]


def test_deploy_files_configure_working_sessions() -> None:
    router_port, gateway_port = free_tcp_port(), free_tcp_port()
    router_endpoint, gateway_endpoint = f"tcp/127.0.0.1:{router_port}", f"tcp/127.0.0.1:{gateway_port}"
    router = ZenohSettings("router", listen=(router_endpoint,), config_file=str(DEPLOY / "zenoh-single-host.json5"))
    gateway = ZenohSettings(
        "peer",
        listen=(gateway_endpoint,),
        connect=(router_endpoint,),
        config_file=str(DEPLOY / "zenoh-gateway-peer.json5"),
    )
    multi_host = ZenohSettings("router", config_file=str(DEPLOY / "zenoh-router.json5")).to_config()
    assert multi_host.get_json("listen/endpoints") == '["tcp/0.0.0.0:7447"]'  # kept from the file
    assert gateway.to_config().get_json("connect/endpoints") == f'["{router_endpoint}"]'  # overridden
    with (
        open_session(router) as router_session,
        open_session(gateway),
        open_session(ZenohSettings("client", connect=(gateway_endpoint,))) as gateway_agent,
        open_session(ZenohSettings("client", connect=(router_endpoint,))) as coordinator,
    ):
        _, inbox = subscribe_queue(coordinator, "test/obs/*")
        received = _publish_until_received(gateway_agent, "test/obs/1", b"via gateway", inbox)
        assert received == ("test/obs/1", b"via gateway")
        with declare_token(gateway_agent, "test/alive/1"):
            deadline = time.monotonic() + 3.0
            while alive_now(router_session, "test/alive/*") != {"test/alive/1"}:
                assert time.monotonic() < deadline, "the gateway agent's token never reached the router"
                time.sleep(0.02)
