"""The Zenoh layer with real sessions, on loopback only (tcp/127.0.0.1, multicast off)."""

from __future__ import annotations

import errno
import queue
import socket
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import zenoh
from waiting import matched_publisher

from runtime.errors import SwarmConnectionError, SwarmInputError
from runtime.wire.transport import (
    ZenohSettings,
    alive_now,
    declare_token,
    free_tcp_port,
    loopback_hub,
    open_loopback_hub,
    open_session,
    port_taken,
    publish,
    round_trip_ms,
    start_on_free_port,
    subscribe,
    subscribe_queue,
    watch_liveliness,
)

REPO = Path(__file__).resolve().parents[2]
DEPLOY = REPO / "deploy"

@pytest.fixture
def hub() -> Iterator[tuple[zenoh.Session, ZenohSettings]]:
    """A router session on a free loopback port and the client settings that reach it."""
    session, member, _ = open_loopback_hub()
    with session:
        yield session, member


def _send_when_matched(
    session: zenoh.Session, key: str, payload: bytes, inbox: queue.Queue[tuple[str, bytes]], timeout_s: float = 10.0
) -> tuple[str, bytes]:
    """Publish ``payload`` once, when a subscriber matches ``key``; what ``inbox`` then receives."""
    publisher = matched_publisher(session, key, timeout_s)
    try:
        publisher.put(payload)
        return inbox.get(timeout=timeout_s)
    finally:
        publisher.undeclare()


def _liveliness_events(session: zenoh.Session, key_expr: str) -> tuple[zenoh.Subscriber, queue.Queue[tuple[str, bool]]]:
    """Token appearances and disappearances on ``key_expr`` as ``(key, alive)`` (tokens alive already come first)."""
    events: queue.Queue[tuple[str, bool]] = queue.Queue()
    return watch_liveliness(session, key_expr, lambda key, alive: events.put((key, alive))), events


def _wait_for(events: queue.Queue[tuple[str, bool]], expected: tuple[str, bool], timeout_s: float = 10.0) -> None:
    """Until ``expected`` comes out of ``events``; fails after ``timeout_s`` (a bound on a hang, not a speed test)."""
    deadline = time.monotonic() + timeout_s
    while (left := deadline - time.monotonic()) > 0:
        try:
            if events.get(timeout=left) == expected:
                return
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
        assert _send_when_matched(sender, "test/data/7", payload, inbox) == ("test/data/7", payload)
        publish(sender, "test/other/7", b"not subscribed")  # outside the key expression: never delivered
        publish(sender, "test/data/8", b"second")
        assert inbox.get(timeout=10.0) == ("test/data/8", b"second")  # in order, and the other key skipped
        assert inbox.empty()

        seen: queue.Queue[tuple[str, bytes]] = queue.Queue()
        callback_subscriber = subscribe(hub_session, "test/cb", lambda key, data: seen.put((key, data)))
        assert _send_when_matched(receiver, "test/cb", b"to the hub", seen) == ("test/cb", b"to the hub")
        callback_subscriber.undeclare()

        hub_watch, hub_events = _liveliness_events(hub_session, "test/alive/*")
        token = declare_token(sender, "test/alive/sender")
        _wait_for(hub_events, ("test/alive/sender", True))  # the token reached the hub
        assert alive_now(hub_session, "test/alive/*") == {"test/alive/sender"}
        watcher, events = _liveliness_events(receiver, "test/alive/*")
        _wait_for(events, ("test/alive/sender", True))  # declared before the watch: history
        token.undeclare()
        _wait_for(events, ("test/alive/sender", False))
        assert alive_now(receiver, "test/alive/*", timeout_s=0.5) == set()
        watcher.undeclare()
        hub_watch.undeclare()


def test_round_trip_ms_statistics_are_consistent() -> None:
    """50 pings after warm-up: ordered statistics, each ping answered within its 1 s timeout (else it raises)."""
    hub_settings, member = loopback_hub(free_tcp_port())
    result = round_trip_ms(hub_settings, member, count=50)
    assert set(result) == {"count", "median_ms", "p90_ms", "min_ms", "max_ms"} and result["count"] == 50
    assert 0 < result["min_ms"] <= result["median_ms"] <= result["p90_ms"] <= result["max_ms"] < 1000.0


def test_round_trip_ms_between_sessions_that_do_not_meet_fails_clearly() -> None:
    """Two separate hubs never exchange a ping: SwarmConnectionError naming the cause, no result."""
    first, _ = loopback_hub(free_tcp_port())
    second, _ = loopback_hub(free_tcp_port())
    with pytest.raises(SwarmConnectionError, match="do the two settings reach each other"):
        round_trip_ms(first, second, count=2)


@pytest.mark.parametrize("count", [1, 0, True, 2.5])
def test_round_trip_ms_refuses_bad_counts(count) -> None:
    hub_settings, member = loopback_hub(free_tcp_port())
    with pytest.raises(SwarmInputError, match="round trip count must be an integer of at least 2"):
        round_trip_ms(hub_settings, member, count=count)


def test_deploy_files_configure_working_sessions() -> None:
    def router(port: int) -> ZenohSettings:
        return ZenohSettings("router", listen=(f"tcp/127.0.0.1:{port}",), config_file=str(DEPLOY / "zenoh-single-host.json5"))

    def gateway(port: int) -> ZenohSettings:
        return ZenohSettings("peer", listen=(f"tcp/127.0.0.1:{port}",), connect=(router_endpoint,),
                             config_file=str(DEPLOY / "zenoh-gateway-peer.json5"))

    router_session, router_port = start_on_free_port(lambda port: open_session(router(port)))
    router_endpoint = f"tcp/127.0.0.1:{router_port}"
    gateway_session, gateway_port = start_on_free_port(lambda port: open_session(gateway(port)))
    gateway_endpoint = f"tcp/127.0.0.1:{gateway_port}"
    multi_host = ZenohSettings("router", config_file=str(DEPLOY / "zenoh-router.json5")).to_config()
    assert multi_host.get_json("listen/endpoints") == '["tcp/0.0.0.0:7447"]'  # kept from the file
    assert gateway(gateway_port).to_config().get_json("connect/endpoints") == f'["{router_endpoint}"]'  # overridden
    with (
        router_session,
        gateway_session,
        open_session(ZenohSettings("client", connect=(gateway_endpoint,))) as gateway_agent,
        open_session(ZenohSettings("client", connect=(router_endpoint,))) as coordinator,
    ):
        _, inbox = subscribe_queue(coordinator, "test/obs/*")
        received = _send_when_matched(gateway_agent, "test/obs/1", b"via gateway", inbox)
        assert received == ("test/obs/1", b"via gateway")
        router_watch, router_events = _liveliness_events(router_session, "test/alive/*")
        with declare_token(gateway_agent, "test/alive/1"):
            _wait_for(router_events, ("test/alive/1", True))  # the gateway agent's token reached the router
            assert alive_now(router_session, "test/alive/*") == {"test/alive/1"}
        router_watch.undeclare()




def test_a_listener_whose_port_was_taken_meanwhile_starts_on_another():
    """Another process takes the port between its pick and the router's bind (here: this test, on the first try):
    the router starts on a fresh port; a failure that is not a taken port is not tried again."""
    tried: list[int] = []
    taken = socket.socket()

    def start(port: int) -> zenoh.Session:
        if not tried:
            taken.bind(("127.0.0.1", port))
            taken.listen()
        tried.append(port)
        return open_session(loopback_hub(port)[0])

    with taken:
        session, port = start_on_free_port(start)
    with session, open_session(loopback_hub(port)[1]) as client:
        assert len(tried) == 2 and port == tried[1] != tried[0] and list(client.info.routers_zid())

    def refused(port: int) -> zenoh.Session:
        tried.append(port)
        raise SwarmInputError(f"bad port {port}")
    with pytest.raises(SwarmInputError, match="bad port"):
        start_on_free_port(refused)
    assert len(tried) == 3
    assert port_taken(OSError(errno.EADDRINUSE, "in use")) and not port_taken(OSError(errno.ECONNREFUSED, "refused"))
