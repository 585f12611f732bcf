"""The Zenoh layer every process of a run shares: settings, sessions, pub/sub, liveliness.

Single-host topology (the default): a star on loopback, no external router, no multicast.
One process (the coordinator or the launcher) opens a *hub* session in ``router`` mode that
listens on ``tcp/127.0.0.1:<port>``; every other process (one agent per robot, tools) opens
a ``client`` session that connects to it. ``loopback_hub(port)`` returns both settings.
Measured on this machine (2 cores) with one Python router session: 50 agent processes
(start, import, open, token) are all alive after 3.1 s, a broadcast gets their 50 answers
back in 17 ms, and after SIGKILLing all of them their tokens are gone within 60 ms; 50
client sessions in one process open in 55 ms. 50 ``peer`` sessions behind the same router
instead learn each other's listeners by gossip and build a full mesh (1225 more links,
3.2 s to open), so agents are clients. The hub is a router, the role Zenoh defines for
brokering, so a multi-host deployment (``deploy/zenoh-router.json5``, run by ``zenohd`` or
the coordinator) only changes the endpoint the clients connect to. Raw round trip
(``round_trip_ms``, median): 0.08-0.15 ms hub-client, 0.2 ms client-hub-client.

A client fails to open at once (``ConnectionError``) when no hub listens: start the hub
first. A process that dies (even by SIGKILL) closes its TCP link, so the hub drops its
liveliness tokens within milliseconds; a host that vanishes without closing its links is
noticed after the Zenoh lease (10 s by default).

Callbacks given to ``subscribe`` and ``watch_liveliness`` run on a thread Zenoh owns, not
the caller's: they must be quick and thread-safe and must not call the Zenoh API (no
``publish`` from a callback; Zenoh forbids it, it may deadlock). To react by publishing,
use ``subscribe_queue`` and work from your own thread. Callback subscribers run until
``undeclare()`` or until the session closes, even if the returned object is dropped.
Sessions also receive their own publications on matching subscribers.
"""

from __future__ import annotations

import dataclasses
import errno
import json
import os
import queue
import random
import re
import socket
import statistics
import threading
import time
import uuid
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import TypeVar

import zenoh

from runtime.errors import SwarmConnectionError, SwarmInputError
from runtime.wire.keys import alive_key, link_alive_key
from runtime.wire.tls_files import check_tls_files

MODES = ("peer", "client", "router")
LOOPBACK = "127.0.0.1"
MAX_WIRE_BYTES = 4 * 2**20 + 2**16  # the largest message (runtime.wire.messages.MAX_MESSAGE_BYTES) and room for Zenoh's framing
T = TypeVar("T")
DROP_WAIT_US = 20_000  # us a sample may wait for a full transmit queue before Zenoh drops it (Zenoh default: 1000)

_ENDPOINT = re.compile(
    r"(?P<proto>tcp|udp|quic|tls)/"
    r"(?P<host>\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9]([A-Za-z0-9.-]*[A-Za-z0-9])?)"
    r":(?P<port>[0-9]{1,5})"
    r"([?#].*)?"
)


def _check_endpoints(field: str, endpoints: object, mode: str) -> tuple[str, ...]:
    if isinstance(endpoints, str) or not isinstance(endpoints, (tuple, list)):
        raise SwarmInputError(f"zenoh {field} must be a list of endpoints, got {endpoints!r}")
    for endpoint in endpoints:
        match = _ENDPOINT.fullmatch(endpoint) if isinstance(endpoint, str) else None
        if match is None:
            raise SwarmInputError(
                f"zenoh {field} endpoint {endpoint!r} is invalid: use <tcp|udp|quic|tls>/<host>:<port>, "
                f"e.g. tcp/{LOOPBACK}:7447"
            )
        port = int(match["port"])
        lowest = 0 if field == "listen" else 1  # listening on port 0 picks a free port
        if not lowest <= port <= 65535:
            raise SwarmInputError(f"zenoh {field} endpoint {endpoint!r}: port {port} is outside [{lowest}, 65535]")
    if field == "listen" and mode == "client" and endpoints:
        raise SwarmInputError(f"a zenoh client cannot listen (listen={list(endpoints)}): use mode peer or router")
    return tuple(endpoints)


@dataclass(frozen=True)
class ZenohSettings:
    """How one process joins the Zenoh network.

    ``listen``/``connect`` are endpoints such as ``tcp/127.0.0.1:7447``. Without
    ``config_file`` an empty ``listen`` means listening nowhere (Zenoh itself would listen
    on every interface); with ``config_file`` (a Zenoh JSON5 file) empty fields keep the
    file's values and non-empty ones, ``mode`` and ``multicast_scouting`` override it.
    """

    mode: str
    listen: tuple[str, ...] = ()
    connect: tuple[str, ...] = ()
    multicast_scouting: bool = False
    config_file: str | None = None

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise SwarmInputError(f"zenoh mode {self.mode!r} is invalid: use one of {', '.join(MODES)}")
        object.__setattr__(self, "listen", _check_endpoints("listen", self.listen, self.mode))
        object.__setattr__(self, "connect", _check_endpoints("connect", self.connect, self.mode))
        if not isinstance(self.multicast_scouting, bool):
            raise SwarmInputError(f"zenoh multicast_scouting must be true or false, got {self.multicast_scouting!r}")
        if self.config_file is not None and not os.path.isfile(self.config_file):
            raise SwarmInputError(f"zenoh config file {self.config_file!r} does not exist")
        if self.mode == "client" and not self.connect and self.config_file is None and not self.multicast_scouting:
            raise SwarmInputError("a zenoh client needs connect endpoints (or multicast scouting, or a config file)")

    def to_config(self) -> zenoh.Config:
        """The ``zenoh.Config`` for ``zenoh.open``."""
        if self.config_file is None:
            config = zenoh.Config()
        else:
            try:
                config = zenoh.Config.from_file(self.config_file)
            except zenoh.ZError as exc:
                raise SwarmInputError(f"zenoh config file {self.config_file!r} is invalid: {zenoh_error_text(exc)}") from None
        config.insert_json5("mode", json.dumps(self.mode))
        if self.listen or self.config_file is None:
            config.insert_json5("listen/endpoints", json.dumps(list(self.listen)))
        if self.connect or self.config_file is None:
            config.insert_json5("connect/endpoints", json.dumps(list(self.connect)))
        config.insert_json5("scouting/multicast/enabled", json.dumps(self.multicast_scouting))
        # A larger message is dropped by the receiving transport before it is reassembled (a 20 MB forgery
        # on a command key neither reaches Python nor stays in the router's buffers).
        config.insert_json5("transport/link/rx/max_message_size", str(MAX_WIRE_BYTES))
        # Zenoh drops a sample whose transmit queue stays full for wait_before_drop (default 1 ms); on a busy
        # host (500 agents on 2 cores) scheduling alone stalls a queue that long, and a dropped answer costs
        # the step the re-send at half its timeout. 20 ms removes those drops and bounds the wait on a dead peer.
        config.insert_json5("transport/link/tx/queue/congestion_control/drop/wait_before_drop", str(DROP_WAIT_US))
        if not self.multicast_scouting:
            # The 500 ms that open() waits for multicast scouting replies would be wasted.
            config.insert_json5("scouting/delay", "0")
        return config

    def to_json(self) -> str:
        """One-line JSON, e.g. for a child process's command line or environment."""
        return json.dumps(dataclasses.asdict(self), separators=(",", ":"))

    @classmethod
    def from_json(cls, text: str) -> ZenohSettings:
        """The settings ``to_json`` wrote; ``SwarmInputError`` for anything else."""
        try:
            data = json.loads(text)
        except (TypeError, json.JSONDecodeError) as exc:
            raise SwarmInputError(f"zenoh settings are not valid JSON: {exc}") from exc
        fields = {field.name for field in dataclasses.fields(cls)}
        if not isinstance(data, dict) or "mode" not in data or not set(data) <= fields:
            optional = sorted(fields - {"mode"})
            raise SwarmInputError(f"zenoh settings must be a JSON object with mode and optionally {optional}")
        return cls(**data)


PORT_TRIES = 5  # ports a listener started on a free port tries before its bind's failure is final
_FIRST_PORT = 10000  # the lowest port free_tcp_port draws
_pick = random.SystemRandom()  # never the same sequence in two processes


def _ephemeral_ports() -> range:
    """The kernel's ephemeral range, from which ``bind(0)`` and every outgoing connection's source port draw
    (Linux; elsewhere the IANA range)."""
    try:
        low, high = map(int, Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split())
    except (OSError, ValueError):
        low, high = 49152, 65535
    return range(low, high + 1)


def free_tcp_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago (another process may still take it: a listener started on it
    tries again on a fresh one when its bind fails, ``start_on_free_port``). Drawn at random below the kernel's
    ephemeral range: a port ``bind(0)`` hands out is, once closed, soon some outgoing connection's source port on a
    busy host."""
    ephemeral = _ephemeral_ports()
    for _ in range(100):
        port = _pick.randrange(_FIRST_PORT, ephemeral.start) if ephemeral.start > _FIRST_PORT + 1000 else 0
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
            try:
                sock.bind((LOOPBACK, port))
            except OSError:
                continue
            return int(sock.getsockname()[1])
    raise SwarmConnectionError(f"no free TCP port on {LOOPBACK} in [{_FIRST_PORT}, {ephemeral.start})")


def port_taken(exc: BaseException) -> bool:
    """Whether ``exc`` (an ``OSError``, or the error of a router or process that could not listen) says the port was
    already in use."""
    return (isinstance(exc, OSError) and exc.errno == errno.EADDRINUSE) or "Address already in use" in str(exc)


def start_on_free_port(start: Callable[[int], T], tries: int = PORT_TRIES) -> tuple[T, int]:
    """``(start(port), port)`` for a fresh ``free_tcp_port()``; a start that fails because another process took the port
    meanwhile (``port_taken``) is tried again on another, ``tries`` times in all."""
    for _ in range(tries - 1):
        port = free_tcp_port()
        try:
            return start(port), port
        except Exception as exc:
            if not port_taken(exc):
                raise
    port = free_tcp_port()
    return start(port), port


def open_loopback_hub(tries: int = PORT_TRIES) -> tuple[zenoh.Session, ZenohSettings, str]:
    """An open router session on a free loopback port (``start_on_free_port``): ``(hub session, members' settings,
    endpoint)``; use the session as ``with``."""
    def start(port: int) -> tuple[zenoh.Session, ZenohSettings]:
        hub, member = loopback_hub(port)
        return open_session(hub), member

    (session, member), _ = start_on_free_port(start, tries)
    return session, member, member.connect[0]


def loopback_hub(port: int) -> tuple[ZenohSettings, ZenohSettings]:
    """``(hub, member)`` settings of the single-host star: a router on ``tcp/127.0.0.1:port`` and clients of it."""
    if isinstance(port, bool) or not isinstance(port, int) or not 1 <= port <= 65535:
        raise SwarmInputError(f"hub port {port!r} is not an integer in [1, 65535]")
    endpoint = f"tcp/{LOOPBACK}:{port}"
    return ZenohSettings("router", listen=(endpoint,)), ZenohSettings("client", connect=(endpoint,))


def zenoh_error_text(exc: BaseException) -> str:
    """A Zenoh error's text for a user: without the Rust source locations it carries (``at src/x.rs:447``)."""
    return _RUST_LOCATION.sub("", str(exc)).strip()


_RUST_LOCATION = re.compile(r"\s*\bat\s+\S+\.rs:\d+(?::\d+)?\.?")


def open_session(settings: ZenohSettings) -> zenoh.Session:
    """An open session; use it as ``with open_session(settings) as session:`` so it is closed.

    The certificates and keys of a config file are checked first (``runtime.wire.tls_files``: a bad file is
    named, not reported as a failure to connect); a failure to connect names the endpoints."""
    config = settings.to_config()
    if settings.config_file is not None:
        check_tls_files(config, f"zenoh config {settings.config_file}")
    try:
        return zenoh.open(config)
    except zenoh.ZError as exc:
        endpoints = list(settings.connect) or json.loads(config.get_json("connect/endpoints")) or []
        if isinstance(endpoints, dict):  # per mode in a config file
            endpoints = [e for per_mode in endpoints.values() for e in per_mode]
        tls = " (its certificate and key files were checked: the router is down, unreachable, or refused them)" \
            if settings.config_file is not None and any(str(e).startswith("tls/") for e in endpoints) else ""
        raise SwarmConnectionError(f"cannot open a zenoh {settings.mode} session (listen={list(settings.listen)}, "
                              f"connect={endpoints}){tls}: {zenoh_error_text(exc)}") from None


def publish(session: zenoh.Session, key: str, payload: bytes) -> None:
    """Put ``payload`` on ``key``."""
    session.put(key, payload)


def subscribe(session: zenoh.Session, key_expr: str, callback: Callable[[str, bytes], object]) -> zenoh.Subscriber[None]:
    """Call ``callback(key, payload)`` for every sample on ``key_expr`` (on a Zenoh thread: see module doc)."""
    return session.declare_subscriber(
        key_expr, lambda sample: callback(str(sample.key_expr), sample.payload.to_bytes())
    )


def subscribe_queue(
    session: zenoh.Session, key_expr: str
) -> tuple[zenoh.Subscriber[None], queue.Queue[tuple[str, bytes]]]:
    """Like ``subscribe`` but samples land as ``(key, payload)`` in an unbounded queue you read from any thread."""
    inbox: queue.Queue[tuple[str, bytes]] = queue.Queue()
    return subscribe(session, key_expr, lambda key, payload: inbox.put((key, payload))), inbox


def declare_token(session: zenoh.Session, key: str) -> zenoh.LivelinessToken:
    """A liveliness token on ``key``, alive until ``undeclare()``, session close or process death.

    Keep a reference: unlike a callback subscriber, a dropped token is undeclared.
    """
    return session.liveliness().declare_token(key)


def watch_liveliness(
    session: zenoh.Session, key_expr: str, on_change: Callable[[str, bool], object]
) -> zenoh.Subscriber[None]:
    """Call ``on_change(key, alive)`` when a token on ``key_expr`` appears or disappears.

    Tokens alive before the call are reported first (``alive=True``). Runs on a Zenoh thread.
    """
    return session.liveliness().declare_subscriber(
        key_expr, lambda sample: on_change(str(sample.key_expr), sample.kind == zenoh.SampleKind.PUT), history=True
    )


def alive_now(session: zenoh.Session, key_expr: str, timeout_s: float = 1.0) -> set[str]:
    """Keys of the tokens alive on ``key_expr``; waits at most ``timeout_s`` seconds (usually about 1 ms)."""
    replies = session.liveliness().get(key_expr, timeout=timeout_s)
    return {str(reply.ok.key_expr) for reply in replies if reply.ok is not None}


def round_trip_ms(settings_a: ZenohSettings, settings_b: ZenohSettings, count: int = 200) -> dict[str, float]:
    """Raw Zenoh ping/pong between two sessions opened here with ``settings_a`` and ``settings_b``.

    The two must reach each other (e.g. both halves of ``loopback_hub``, or two clients of a
    running hub). Each ping is a 64-byte put from A that B's thread answers with a put;
    returns ``{"count", "median_ms", "p90_ms", "min_ms", "max_ms"}`` (milliseconds) after warm-up.
    """
    if isinstance(count, bool) or not isinstance(count, int) or count < 2:
        raise SwarmInputError(f"round trip count must be an integer of at least 2, got {count!r}")
    prefix = f"_transport/rtt/{uuid.uuid4().hex}"
    with open_session(settings_a) as a, open_session(settings_b) as b:
        pings = b.declare_subscriber(f"{prefix}/ping")  # a channel, so B answers from its own thread

        def pong() -> None:
            for sample in pings:  # ends when the subscriber is undeclared
                b.put(f"{prefix}/pong", sample.payload)

        ponger = threading.Thread(target=pong, name="zenoh-pong", daemon=True)
        ponger.start()
        pongs: queue.SimpleQueue[bytes] = queue.SimpleQueue()
        a.declare_subscriber(f"{prefix}/pong", lambda sample: pongs.put(sample.payload.to_bytes()))
        ping = _Pinger(a, f"{prefix}/ping", pongs)
        deadline = time.monotonic() + 5.0
        while not ping(timeout_s=0.05):  # until B's subscription has reached A
            if time.monotonic() > deadline:
                raise SwarmConnectionError("no pong within 5 s: do the two settings reach each other?")
        for _ in range(20):
            ping(timeout_s=1.0)
        times = []
        for _ in range(count):
            start = time.perf_counter()
            if not ping(timeout_s=1.0):
                raise SwarmConnectionError("a ping got no pong within 1 s")
            times.append((time.perf_counter() - start) * 1e3)
        pings.undeclare()
        ponger.join(timeout=1.0)
    return {
        "count": count,
        "median_ms": statistics.median(times),
        "p90_ms": statistics.quantiles(times, n=10)[-1],
        "min_ms": min(times),
        "max_ms": max(times),
    }


class _Pinger:
    """Sends numbered 64-byte pings; a call is True when its own pong came back within ``timeout_s``."""

    def __init__(self, session: zenoh.Session, key: str, pongs: queue.SimpleQueue[bytes]) -> None:
        self.session, self.key, self.pongs, self.seq = session, key, pongs, 0

    def __call__(self, timeout_s: float) -> bool:
        self.seq += 1
        tag = self.seq.to_bytes(8, "little")
        self.session.put(self.key, tag + bytes(56))
        deadline = time.monotonic() + timeout_s
        while (left := deadline - time.monotonic()) > 0:
            try:
                if self.pongs.get(timeout=left)[:8] == tag:  # skip late pongs of earlier pings
                    return True
            except queue.Empty:
                break
        return False


def claim_identities(session: zenoh.Session, run: str, robots: Iterable[int] = (), ports: Iterable[str] = ()) -> None:
    """Refuse (``SwarmInputError``) to serve a robot or port of ``run`` whose liveliness token is already alive.

    Call before declaring the tokens: a second agent of a robot or a second link of a port would obey (or send)
    every command twice. A process killed by any signal loses its token within milliseconds, so a restarted one
    is admitted."""
    wanted = {alive_key(run, r): f"robot {r} of run {run} already has a live agent" for r in robots}
    wanted |= {link_alive_key(run, p): f"port {p} of run {run} already has a live link" for p in ports}
    if not wanted:
        return
    alive = alive_now(session, f"swarm/{run}/alive/**")
    taken = sorted(key for key in wanted if key in alive)
    if taken:
        raise SwarmInputError(f"{wanted[taken[0]]} (its liveliness token {taken[0]} is alive): stop that process first"
                              + (f"; also taken: {', '.join(taken[1:])}" if taken[1:] else ""))
