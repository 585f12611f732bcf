"""``estop_under_flood`` of ``swarm bench faults``: emergency stops while the TLS router is flooded.

The deploy/ setup on loopback: ``swarm certs`` makes a lab CA and the router, gateway, coordinator
and estop certificates; ``swarm router`` runs deploy/zenoh-router-tls-acl.json5 (mutual TLS, access
control) with its two listeners on free ports: the public one (robots, coordinator, tools) and the
operator one (the stop path, deploy/README.md "The stop path"). One ``swarm agent`` process hosts
``robots`` simulated agents with the gateway identity (deploy/zenoh-gateway-tls.json5) on the public
listener. Once every agent is alive, this process floods the public listener for ``duration_s``:
``connections`` TCP connections that never say a word, each one the router closes opened again at
once (a sustained flood). Throughout the flood and for ``after_s`` after it closed, one cycle a
second:

* a probe of the public listener: a mutual-TLS handshake with the coordinator identity, given 1 s
  (``public_blocked`` counts those that did not complete: the flood is real);
* a stop as ``swarm estop --zenoh-config zenoh-estop-tls.json5`` sends it: a new session with the
  estop identity through the operator listener, the run's ``EmergencyStop``, the agents'
  ``EstopAck``s collected.

A robot is *reached* by a stop when its agent acknowledged it; a stop's time is from its start
(before its session is opened, so a router that cannot take new sessions shows here) to the last
acknowledgement's stamp (one host, one clock). ``reached`` is the fewest robots a stop reached,
``ms_max`` the longest stop, ``late`` the stops that did not reach every robot within 1 s.
"""

from __future__ import annotations

import json
import resource
import selectors
import socket
import ssl
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, cast

import numpy as np

from coordinator.node.stop import collect_acks, publish_estop
from inchworm.certs import make_certs, parse_host
from inchworm.processes import stop_all
from inchworm.spawn import Spawned
from inchworm.specs import AgentHostSpec, RouterSpec
from runtime.models.trajectory import random_trajectory
from runtime.wire.keys import alive_wildcard, estop_ack_key
from runtime.wire.messages import EmergencyStop
from runtime.wire.transport import ZenohSettings, alive_now, free_tcp_port, open_session, subscribe_queue

DEPLOY = Path(__file__).resolve().parents[2] / "deploy"
CERT_DIR = "/etc/swarm/certs/"
START_S = 60.0
CYCLE_S = 1.0  # one probe and one stop a second
DEADLINE_MS = 1000.0  # a stop must reach every robot within this
PROBE_S = 1.0  # a TLS handshake on the public listener given this long


def _rewrite(src: Path, out: Path, replacements: dict[str, str]) -> Path:
    text = src.read_text()
    for old, new in replacements.items():
        if old not in text:
            raise RuntimeError(f"{old!r} is no longer in {src}: update the bench")
        text = text.replace(old, new)
    out.write_text(text)
    return out


def _client(tmp: Path, certs: Path, config: str, identity: str, endpoint: str) -> ZenohSettings:
    """deploy/``config`` with the certificates of ``identity`` in ``certs``, connecting to ``endpoint``."""
    dialled = {"zenoh-gateway-tls.json5": "tls/coordinator-pc.local:7447", "zenoh-coordinator-tls.json5": "tls/127.0.0.1:7447",
               "zenoh-estop-tls.json5": "tls/127.0.0.1:7449"}[config]
    out = _rewrite(DEPLOY / config, tmp / f"{identity}.json5", {
        f"{CERT_DIR}ca.pem": str(certs / "ca.pem"), f"{CERT_DIR}{identity}.": f"{certs / identity}.", dialled: endpoint})
    return ZenohSettings("client", config_file=str(out))


def idle_connections(port: int, connections: int) -> list[socket.socket]:
    """``connections`` TCP connections to 127.0.0.1:``port`` that never send a byte."""
    return [_idle_connection(port) for _ in range(connections)]


def _idle_connection(port: int) -> socket.socket:
    sock = socket.socket()
    sock.setblocking(False)
    try:
        sock.connect(("127.0.0.1", port))
    except (BlockingIOError, ConnectionRefusedError):
        pass
    return sock


class Flood:
    """``connections`` idle TCP connections to 127.0.0.1:``port`` held while the ``with`` block runs: a
    connection the router closes (or refuses) is opened again at once. ``reopened`` counts those."""

    def __init__(self, port: int, connections: int) -> None:
        self.port, self.connections, self.reopened = port, connections, 0
        self._selector = selectors.DefaultSelector()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._hold, name="flood", daemon=True)

    def __enter__(self) -> Flood:
        for sock in idle_connections(self.port, self.connections):
            self._selector.register(sock, selectors.EVENT_READ)
        self._thread.start()
        return self

    def _hold(self) -> None:
        while not self._stop.is_set():
            for key, _events in self._selector.select(0.2):
                sock = cast(socket.socket, key.fileobj)
                try:
                    if sock.recv(64):  # a TLS server says nothing first; data would be a surprise, keep the connection
                        continue
                except BlockingIOError:
                    continue
                except OSError:
                    pass
                self._selector.unregister(sock)
                sock.close()
                self._selector.register(_idle_connection(self.port), selectors.EVENT_READ)
                self.reopened += 1

    def __exit__(self, *_exc: object) -> None:
        self._stop.set()
        self._thread.join()
        for key in list(self._selector.get_map().values()):
            cast(socket.socket, key.fileobj).close()
        self._selector.close()


def tls_handshake_ok(port: int, certs: Path, identity: str, timeout_s: float = PROBE_S) -> bool:
    """Whether a mutual-TLS handshake with ``identity`` on 127.0.0.1:``port`` completes within ``timeout_s``."""
    context = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
    context.load_verify_locations(certs / "ca.pem")
    context.load_cert_chain(certs / f"{identity}.pem", certs / f"{identity}.key")
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=timeout_s) as raw, \
                context.wrap_socket(raw, server_hostname="127.0.0.1"):
            return True
    except (OSError, ssl.SSLError):
        return False


def _limit_files(files: int) -> None:
    resource.setrlimit(resource.RLIMIT_NOFILE, (files, files))


def stop_once(settings: ZenohSettings, run_id: str, robots: int, ack_timeout_s: float) -> list[float]:
    """What ``swarm estop`` does: a new session, the run's ``EmergencyStop``, the agents' acknowledgements;
    the ms from the start (before the session) to each agent's acknowledgement."""
    start_ns = time.time_ns()
    try:
        with open_session(settings) as operator:
            _sub, inbox = subscribe_queue(operator, estop_ack_key(run_id))
            stop = EmergencyStop(run=run_id, step=0, source="swarm bench faults", reason="estop under flood")
            sent = publish_estop(operator, stop)
            acks = collect_acks(inbox, stop.stamp_ns, sent[0] + ack_timeout_s, agents=robots)
    except ConnectionError:
        return []
    return [(ack.stamp_ns - start_ns) / 1e6 for (by, _name), ack in acks.items() if by == "agent"]


def estop_under_flood(robots: int = 10, connections: int = 3000, duration_s: float = 60.0, after_s: float | None = None,
                      ack_timeout_s: float = 2.0, say: Callable[[str], None] | None = None, path: str = "operator",
                      router_files: int | None = None) -> dict[str, Any]:
    """``{"connections", "tls", "robots", "reached", "ms_max", "duration_s", "after_s", "stops", "late", "probes",
    "public_blocked"}`` (``after_s`` defaults to ``min(duration_s, 60)``; ``ms_max`` None if no robot was reached).
    ``path="public"``: the stops go as before the operator listener, with the coordinator identity through the
    flooded public listener (the comparison in docs/benchmarks.md). ``router_files``: the router may open that many
    files (soft and hard limit; default: this process's limits)."""
    after_s = min(duration_s, 60.0) if after_s is None else after_s
    procs: list[subprocess.Popen[Any]] = []
    run_id = f"flood{int(time.time())}"
    stops: list[list[float]] = []
    probes: list[bool] = []
    with tempfile.TemporaryDirectory(prefix="swarm-bench-flood-") as tmp_name:
        tmp = Path(tmp_name)
        certs = tmp / "certs"
        make_certs(certs, [parse_host(h) for h in ("router=127.0.0.1,localhost", "gateway", "coordinator", "estop")])
        port, operator_port = free_tcp_port(), free_tcp_port()
        public, operator = f"tls/127.0.0.1:{port}", f"tls/127.0.0.1:{operator_port}"
        router_config = _rewrite(DEPLOY / "zenoh-router-tls-acl.json5", tmp / "router.json5", {CERT_DIR: f"{certs}/"})
        gateway = _client(tmp, certs, "zenoh-gateway-tls.json5", "gateway", public)
        coordinator = _client(tmp, certs, "zenoh-coordinator-tls.json5", "coordinator", public)
        estop = _client(tmp, certs, "zenoh-estop-tls.json5", "estop", operator)
        traj = random_trajectory(robots, 1, np.random.default_rng(0))
        traj.save(tmp / "traj.json")
        try:
            router = Spawned(RouterSpec(config=str(router_config), listen=(public, operator)), stdout=subprocess.DEVNULL,
                             stderr=subprocess.PIPE, text=True, preexec_fn=None if router_files is None else lambda: _limit_files(router_files))
            procs.append(router)
            if router.stderr is None or "listening" not in router.stderr.readline():
                raise RuntimeError("the TLS router did not start")
            procs.append(Spawned(AgentHostSpec(run_id=run_id, robots=tuple(range(robots)), trajectory=str(tmp / "traj.json"),
                                               zenoh_config=str(gateway.config_file)), stderr=subprocess.DEVNULL))
            with open_session(coordinator) as observer:
                deadline = time.monotonic() + START_S
                while len(alive_now(observer, alive_wildcard(run_id))) < robots:
                    if time.monotonic() > deadline or any(p.poll() is not None for p in procs):
                        raise RuntimeError(f"the {robots} agents did not come up over TLS within {START_S:.0f} s")
                    time.sleep(0.1)

            def cycles(seconds: float, phase: str) -> None:
                end = time.monotonic() + seconds
                while (now := time.monotonic()) < end:
                    probes.append(tls_handshake_ok(port, certs, "coordinator"))
                    stops.append(stop_once(estop if path == "operator" else coordinator, run_id, robots, ack_timeout_s))
                    if say and (len(stops) % 30 == 0 or path == "public" or router_files is not None):
                        say(f"estop under flood: {phase}, {len(stops)} stops, the last reached {len(stops[-1])} robots "
                            f"({max(stops[-1], default=float('nan')):.0f} ms); public TLS handshake {'ok' if probes[-1] else 'blocked'}")
                    time.sleep(max(0.0, now + CYCLE_S - time.monotonic()))

            with Flood(port, connections):
                cycles(duration_s, "flood")
            cycles(after_s, "after the flood")
        finally:
            stop_all(procs)
    reached = [len(ms) for ms in stops]
    times = [max(ms) for ms in stops if ms]
    return {"connections": connections, "tls": True, "robots": robots, "reached": min(reached, default=0),
            "ms_max": round(max(times), 1) if times else None, "duration_s": duration_s, "after_s": after_s, "stops": len(stops),
            "late": sum(len(ms) < robots or max(ms) > DEADLINE_MS for ms in stops), "probes": len(probes),
            "public_blocked": probes.count(False)}


def main(argv: list[str]) -> None:
    """``python -m inchworm.bench.estop_flood [ROBOTS [CONNECTIONS [DURATION_S [AFTER_S [operator|public [ROUTER_FILES]]]]]]``:
    the JSON on stdout, progress on stderr."""
    robots = int(argv[0]) if argv else 10
    connections = int(argv[1]) if len(argv) > 1 else 3000
    duration_s = float(argv[2]) if len(argv) > 2 else 60.0
    after_s = float(argv[3]) if len(argv) > 3 else None
    path = argv[4] if len(argv) > 4 else "operator"
    if path not in ("operator", "public"):
        raise SystemExit(f"estop_flood: the stop path is operator or public, not {path!r}")
    router_files = int(argv[5]) if len(argv) > 5 else None
    print(json.dumps(estop_under_flood(robots, connections, duration_s, after_s, say=lambda text: print(text, file=sys.stderr, flush=True),
                                       path=path, router_files=router_files)))


if __name__ == "__main__":
    main(sys.argv[1:])
