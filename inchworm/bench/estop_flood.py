"""``estop_under_flood`` of ``swarm bench faults``: an emergency stop while the TLS router is flooded.

The deploy/ setup on loopback: ``swarm certs`` makes a lab CA and the router, gateway and
coordinator certificates; ``swarm router`` runs deploy/zenoh-router-tls-acl.json5 (mutual TLS,
access control) on a free port; one ``swarm agent`` process hosts ``robots`` simulated agents with
the gateway identity (deploy/zenoh-gateway-tls.json5). Once every agent is alive, this process
opens ``connections`` TCP connections to the router's TLS port that never say a word (each kept
open), then does what ``swarm estop`` does with the coordinator identity: opens a new session,
publishes the run's ``EmergencyStop`` and collects the agents' ``EstopAck``s. A robot is *reached*
when its agent acknowledged; ``ms_max`` is the longest time from the start of the stop (before
its session is opened, so a router that cannot take new sessions shows here) to an
acknowledgement's stamp (one host, one clock).
"""

from __future__ import annotations

import json
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from coordinator.stop import collect_acks, publish_estop
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


def _rewrite(src: Path, out: Path, replacements: dict[str, str]) -> Path:
    text = src.read_text()
    for old, new in replacements.items():
        if old not in text:
            raise RuntimeError(f"{old!r} is no longer in {src}: update the bench")
        text = text.replace(old, new)
    out.write_text(text)
    return out


def _client(tmp: Path, certs: Path, identity: str, endpoint: str) -> ZenohSettings:
    config = _rewrite(DEPLOY / "zenoh-gateway-tls.json5", tmp / f"{identity}.json5", {
        f"{CERT_DIR}ca.pem": str(certs / "ca.pem"), f"{CERT_DIR}gateway.": f"{certs / identity}.",
        "tls/coordinator-pc.local:7447": endpoint})
    return ZenohSettings("client", config_file=str(config))


def idle_connections(port: int, connections: int) -> list[socket.socket]:
    """``connections`` TCP connections to 127.0.0.1:``port`` that never send a byte."""
    sockets = []
    for _ in range(connections):
        sock = socket.socket()
        sock.setblocking(False)
        try:
            sock.connect(("127.0.0.1", port))
        except BlockingIOError:
            pass
        sockets.append(sock)
    return sockets


def estop_under_flood(robots: int = 10, connections: int = 3000, ack_timeout_s: float = 5.0) -> dict:
    """``{"connections", "tls", "robots", "reached", "ms_max"}`` (``ms_max`` None if no robot was reached)."""
    procs: list[subprocess.Popen] = []
    sockets: list[socket.socket] = []
    run_id = f"flood{int(time.time())}"
    with tempfile.TemporaryDirectory(prefix="swarm-bench-flood-") as tmp_name:
        tmp = Path(tmp_name)
        certs = tmp / "certs"
        make_certs(certs, [parse_host(h) for h in ("router=127.0.0.1,localhost", "gateway", "coordinator")])
        port = free_tcp_port()
        endpoint = f"tls/127.0.0.1:{port}"
        router_config = _rewrite(DEPLOY / "zenoh-router-tls-acl.json5", tmp / "router.json5", {CERT_DIR: f"{certs}/"})
        gateway, coordinator = _client(tmp, certs, "gateway", endpoint), _client(tmp, certs, "coordinator", endpoint)
        traj = random_trajectory(robots, 1, np.random.default_rng(0))
        traj.save(tmp / "traj.json")
        try:
            router = Spawned(RouterSpec(config=str(router_config), listen=(endpoint,)), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                             text=True)
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
                sockets = idle_connections(port, connections)
                time.sleep(0.5)  # the router is busy with them
                start_ns = time.time_ns()
                with open_session(coordinator) as operator:  # what swarm estop does
                    _sub, inbox = subscribe_queue(operator, estop_ack_key(run_id))
                    stop = EmergencyStop(run=run_id, step=0, source="swarm bench faults", reason="estop under flood")
                    sent = publish_estop(operator, stop)
                    acks = collect_acks(inbox, stop.stamp_ns, sent[0] + ack_timeout_s)
        finally:
            for sock in sockets:
                sock.close()
            stop_all(procs)
    reached = [ack for (by, _name), ack in acks.items() if by == "agent"]
    ms = [(ack.stamp_ns - start_ns) / 1e6 for ack in reached]
    return {"connections": connections, "tls": True, "robots": robots, "reached": len(reached),
            "ms_max": round(max(ms), 1) if ms else None}


if __name__ == "__main__":
    print(json.dumps(estop_under_flood(*(int(a) for a in sys.argv[1:]))))
