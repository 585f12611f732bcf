"""Multi-host deployment pieces with real processes: ``swarm router``, ``swarm certs``, mutual TLS
and access control (deploy/zenoh-router-tls-acl.json5), and network namespaces.

Loopback only (``tcp/127.0.0.1`` / ``tls/127.0.0.1`` on free ports) except the netns test,
which uses private 10.x veth addresses; multicast scouting is off everywhere. Every child
process is stopped by its own pid in ``finally`` (SIGTERM, then SIGKILL after 5 s).
Certificates are made by ``swarm certs`` (the openssl CLI) into pytest's tmp directories.
"""

from __future__ import annotations

import json
import os
import queue
import shutil
import signal
import subprocess
import sys
import threading
import time
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest

from runtime.wire.keys import alive_key, coord_alive_key, robot_key
from runtime.wire.messages import MotionCommand, Status, decode, encode, message_key
from runtime.wire.transport import (
    DROP_WAIT_US,
    MAX_WIRE_BYTES,
    ZenohSettings,
    declare_token,
    free_tcp_port,
    open_session,
    publish,
    subscribe_queue,
    watch_liveliness,
)
from swarm_cli.main import main as swarm_main

REPO = Path(__file__).resolve().parents[2]
DEPLOY = REPO / "deploy"
ENV = {**os.environ, "PYTHONPATH": str(REPO)}
CERT_DIR = "/etc/swarm/certs/"

# One side of a two-process exchange: publishes "hello from NAME" on PUB_KEY every 0.1 s
# until it has received the other side's message on SUB_KEY, then a little longer (so the
# other side gets its message too); prints {"name", "received"} and exits 0 if it received.
SIDE = """
import json, queue, sys, time
from runtime.wire.transport import ZenohSettings, open_session, publish, subscribe_queue
settings, sub_key, pub_key, name = ZenohSettings.from_json(sys.argv[1]), sys.argv[2], sys.argv[3], sys.argv[4]
received, extra, deadline = None, 0, time.monotonic() + 20.0
with open_session(settings) as session:
    sub, inbox = subscribe_queue(session, sub_key)
    while time.monotonic() < deadline and extra < 10:
        publish(session, pub_key, f"hello from {name}".encode())
        if received is None:
            try:
                received = inbox.get(timeout=0.1)[1].decode()
            except queue.Empty:
                pass
        else:
            extra += 1
            time.sleep(0.05)
print(json.dumps({"name": name, "received": received}), flush=True)
sys.exit(0 if received else 1)
"""


class Child:
    """A child process; a thread collects its stderr lines so the pipe never fills."""

    def __init__(self, cmd: list[str]) -> None:
        self.cmd = cmd
        self.proc = subprocess.Popen(cmd, cwd=REPO, env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        self.stderr: list[str] = []
        self._lines: queue.Queue[str] = queue.Queue()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        for line in self.proc.stderr:
            self.stderr.append(line)
            self._lines.put(line)

    def wait_line(self, needle: str, timeout_s: float) -> str:
        """The first stderr line containing ``needle``; fails if the process ends or ``timeout_s`` passes."""
        deadline = time.monotonic() + timeout_s
        while (left := deadline - time.monotonic()) > 0:
            try:
                line = self._lines.get(timeout=min(left, 0.1))
            except queue.Empty:
                if self.proc.poll() is not None and self._lines.empty():
                    break
                continue
            if needle in line:
                return line
        raise AssertionError(f"{self.cmd[:4]}...: no {needle!r} on stderr within {timeout_s} s; stderr: {''.join(self.stderr)}")

    def finish(self, timeout_s: float) -> tuple[int, str]:
        """Exit status and stdout once the process ends by itself within ``timeout_s``."""
        try:
            code = self.proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            raise AssertionError(f"{self.cmd[:4]}... still running after {timeout_s} s; stderr: {''.join(self.stderr)}") from None
        return code, self.proc.stdout.read()


def stop(children: list[Child]) -> None:
    """SIGTERM every child still running (by pid), SIGKILL those still running 5 s later."""
    for child in children:
        if child.proc.poll() is None:
            os.kill(child.proc.pid, signal.SIGTERM)
    deadline = time.monotonic() + 5.0
    for child in children:
        try:
            child.proc.wait(timeout=max(0.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            os.kill(child.proc.pid, signal.SIGKILL)
            child.proc.wait()


def router_cmd(*args: str) -> list[str]:
    return [sys.executable, "-m", "swarm_cli.router", *args]


def side_cmd(settings: ZenohSettings, sub_key: str, pub_key: str, name: str, prefix: tuple[str, ...] = ()) -> list[str]:
    return [*prefix, sys.executable, "-c", SIDE, settings.to_json(), sub_key, pub_key, name]


def make_certs(out: Path, *hosts: str) -> dict:
    """Run ``swarm certs --out OUT --host ... --json`` as a process; its JSON result."""
    cmd = [sys.executable, "-m", "swarm_cli.main", "certs", "--out", str(out), "--json"]
    for host in hosts:
        cmd += ["--host", host]
    proc = subprocess.run(cmd, cwd=REPO, env=ENV, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.strip().splitlines()[-1])


def rewrite(src: Path, out: Path, replacements: dict[str, str]) -> Path:
    """Copy the deploy file ``src`` to ``out`` with each ``old`` text (which must occur) replaced."""
    text = src.read_text()
    for old, new in replacements.items():
        assert old in text, f"{old!r} not in {src}"
        text = text.replace(old, new)
    out.write_text(text)
    return out


def client_config(tmp: Path, certs: Path, identity: str, endpoint: str, *, mtls: bool = True, ca: Path | None = None) -> ZenohSettings:
    """Client settings from deploy/zenoh-gateway-tls.json5 with ``identity``'s certificate, dialling ``endpoint``."""
    out = tmp / f"client-{identity}-{uuid.uuid4().hex[:6]}.json5"
    replacements = {
        f"{CERT_DIR}ca.pem": str(ca or certs / "ca.pem"),
        f"{CERT_DIR}gateway.": f"{certs / identity}.",
        "tls/coordinator-pc.local:7447": endpoint,
    }
    if not mtls:
        replacements["enable_mtls: true"] = "enable_mtls: false"
    return ZenohSettings("client", config_file=str(rewrite(DEPLOY / "zenoh-gateway-tls.json5", out, replacements)))


@pytest.fixture(scope="module")
def certs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A lab CA with router, coordinator, gateway, estop and intruder certificates (``swarm certs``)."""
    out = tmp_path_factory.mktemp("certs")
    result = make_certs(out, "router", "coordinator", "gateway", "estop", "intruder")
    assert set(result["hosts"]) == {"router", "coordinator", "gateway", "estop", "intruder"} and not result["ca"]["reused"]
    return out


# -- swarm certs -------------------------------------------------------------------------------


def test_certs_files_sans_and_ca_reuse(certs: Path, tmp_path: Path) -> None:
    for name in ("ca", "router", "coordinator", "gateway", "intruder"):
        assert (certs / f"{name}.key").stat().st_mode & 0o777 == 0o600
        assert (certs / f"{name}.pem").stat().st_mode & 0o777 == 0o644
    out = tmp_path / "c"
    out.mkdir()
    shutil.copy(certs / "ca.pem", out / "ca.pem")
    shutil.copy(certs / "ca.key", out / "ca.key")
    result = make_certs(out, "router=10.0.0.5,coord-pc.local,::1")
    assert result["ca"]["reused"]
    assert result["hosts"]["router"]["sans"] == ["DNS:router", "IP:10.0.0.5", "DNS:coord-pc.local", "IP:::1", "IP:127.0.0.1"]
    text = subprocess.run(["openssl", "x509", "-in", str(out / "router.pem"), "-noout", "-subject", "-ext", "subjectAltName"],
                          capture_output=True, text=True, check=True).stdout
    assert "CN = router" in text or "CN=router" in text
    assert "IP Address:10.0.0.5" in text and "DNS:coord-pc.local" in text and "IP Address:127.0.0.1" in text
    verify = subprocess.run(["openssl", "verify", "-CAfile", str(certs / "ca.pem"), str(out / "router.pem")],
                            capture_output=True, text=True)
    assert verify.returncode == 0, verify.stderr


def test_certs_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert swarm_main(["certs", "--out", str(tmp_path / "x"), "--host", "bad_name"]) == 2
    assert swarm_main(["certs", "--out", str(tmp_path / "x"), "--host", "ok=not an address"]) == 2
    (tmp_path / "lone").mkdir()
    (tmp_path / "lone" / "ca.pem").write_text("x")
    assert swarm_main(["certs", "--out", str(tmp_path / "lone")]) == 2
    err = capsys.readouterr().err
    assert "bad_name" in err and "neither an IP address nor a DNS name" in err and "only one of ca.pem and ca.key" in err
    empty = tmp_path / "empty-path"
    empty.mkdir()
    proc = subprocess.run([sys.executable, "-m", "swarm_cli.certs", "--out", str(tmp_path / "y")], cwd=REPO,
                          env={**ENV, "PATH": str(empty)}, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and "openssl command was not found" in proc.stderr and "Traceback" not in proc.stderr


# -- swarm router --------------------------------------------------------------------------------


def test_router_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert swarm_main(["router", "--listen", "tcp/nowhere"]) == 2
    assert swarm_main(["router", "--listen", "tcp/127.0.0.1:0"]) == 2
    assert swarm_main(["router", "--config", str(tmp_path / "missing.json5")]) == 2
    (tmp_path / "bad.json5").write_text("{ mode: ")
    assert swarm_main(["router", "--config", str(tmp_path / "bad.json5")]) == 2
    assert swarm_main(["router", "--config", str(DEPLOY / "zenoh-router-tls-acl.json5")]) == 2  # /etc/swarm/certs absent
    err = capsys.readouterr().err
    assert "tcp/nowhere" in err and "fixed port" in err and "missing.json5" in err and "bad.json5" in err
    assert "transport/link/tls/" in err and "is not a readable file" in err and "Traceback" not in err


def test_router_relays_between_two_client_processes(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Plain tcp: a gateway-side and a coordinator-side process, each a client of the router only."""
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    client = ZenohSettings("client", connect=(endpoint,))
    cmd_key, status_key = robot_key("deploy", 0, "cmd"), robot_key("deploy", 0, "status")
    children: list[Child] = []
    try:
        router = Child(router_cmd("--listen", endpoint, "--json"))
        children.append(router)
        router.wait_line("swarm router: listening on", 15)
        ready = json.loads(router.proc.stdout.readline())
        assert ready["listen"] == [endpoint] and ready["zid"]
        assert swarm_main(["router", "--listen", endpoint]) == 2  # the port is taken
        assert "Address already in use" in capsys.readouterr().err
        gateway = Child(side_cmd(client, cmd_key, status_key, "gateway"))
        coordinator = Child(side_cmd(client, status_key, cmd_key, "coordinator"))
        children += [gateway, coordinator]
        for child, other in ((gateway, "coordinator"), (coordinator, "gateway")):
            code, out = child.finish(30)
            assert code == 0 and json.loads(out)["received"] == f"hello from {other}", child.stderr
        os.kill(router.proc.pid, signal.SIGTERM)
        assert router.proc.wait(timeout=10) == 0
        router.wait_line("swarm router: stopped", 5)
    finally:
        stop(children)


# -- router limits against connection floods --------------------------------------------------------

FLOOD = 3000


@pytest.mark.parametrize("config", ["zenoh-router.json5", "zenoh-single-host.json5", "zenoh-router-tls-acl.json5"])
def test_router_configs_set_zenohs_transport_limits(config: str) -> None:
    """The keys are Zenoh 1.10's (a misspelt key would be rejected or ignored: read the values back)."""
    import zenoh

    loaded = zenoh.Config.from_file(str(DEPLOY / config))
    unicast = json.loads(loaded.get_json("transport/unicast"))
    assert (unicast["accept_timeout"], unicast["accept_pending"], unicast["max_sessions"], unicast["max_links"]) == (1000, 100, 256, 1)
    assert json.loads(loaded.get_json("transport/link/tx/lease")) == 3000
    assert json.loads(loaded.get_json("transport/link/rx/max_message_size")) == MAX_WIRE_BYTES


def test_idle_connection_flood_does_not_starve_new_sessions(tmp_path: Path) -> None:
    """3000 TCP connections opened at once that never handshake: a Zenoh session and `swarm estop` still get through.

    With Zenoh's defaults (accept_timeout 10 s, accept_pending 100) such a flood stopped new
    sessions for about 5 minutes; deploy/zenoh-router.json5 drops idle handshakes after 1 s.
    """
    import socket

    from inchworm.bench.estop_flood import idle_connections

    port = free_tcp_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    children: list[Child] = []
    sockets: list[socket.socket] = []
    try:
        router = Child(router_cmd("--config", str(DEPLOY / "zenoh-router.json5"), "--listen", endpoint))
        children.append(router)
        router.wait_line("swarm router: listening on", 15)
        sockets = idle_connections(port, FLOOD)
        start = time.monotonic()
        attempts = 0
        while True:  # each attempt waits up to Zenoh's open_timeout (10 s), as a user re-running a command would
            attempts += 1
            try:
                with open_session(ZenohSettings("client", connect=(endpoint,))):
                    session_s = time.monotonic() - start
                break
            except ConnectionError:
                assert time.monotonic() - start < 60, f"no session within 60 s of the flood ({attempts} attempts)"
        start = time.monotonic()
        tries = 0
        while True:  # re-run as an operator would when the command says it could not connect (a busy machine)
            tries += 1
            estop = subprocess.run([sys.executable, "-m", "swarm_cli.main", "estop", "--run=flood", f"--hub={endpoint}"],
                                   capture_output=True, text=True, timeout=120, env=ENV)
            if estop.returncode != 2 or "connect" not in estop.stderr or time.monotonic() - start > 30:
                break
        estop_s = time.monotonic() - start
        print(f"after {FLOOD} idle connections: a session opened after {session_s:.2f} s ({attempts} attempts), "
              f"then swarm estop took {estop_s:.2f} s ({tries} runs; busy machine)")
        assert estop.returncode == 1, estop.stderr  # it got through; nobody runs "flood", so nobody acknowledged
        assert "no agent or link acknowledged it" in estop.stderr
        assert session_s < 30 and estop_s < 30  # Zenoh's defaults: about 300 s
    finally:
        for sock in sockets:
            sock.close()
        stop(children)


def test_the_stop_gets_through_a_flood_of_the_public_listener(certs: Path, tmp_path: Path) -> None:
    """300 idle connections held on the TLS router's public listener jam it once their TLS handshakes time out
    (1 s here, ``#tls_handshake_timeout_ms``; Zenoh's default 10 s): Zenoh's TLS accept loop then sleeps 100 ms
    after each, so a mutual-TLS handshake there does not complete within 1 s. `swarm estop --zenoh-config
    zenoh-estop-tls.json5` through the operator listener is acknowledged by every agent during the flood, and
    a stop right after the flood closed (the public listener still draining it) reaches every agent too."""
    import numpy as np

    from inchworm.bench.estop_flood import Flood, stop_once, tls_handshake_ok
    from runtime.models.trajectory import random_trajectory
    from runtime.wire.keys import alive_wildcard
    from runtime.wire.transport import alive_now

    robots, run = 5, f"flood{uuid.uuid4().hex[:8]}"
    port, operator_port = free_tcp_port(), free_tcp_port()
    public, operator = f"tls/127.0.0.1:{port}", f"tls/127.0.0.1:{operator_port}"
    router_config = rewrite(DEPLOY / "zenoh-router-tls-acl.json5", tmp_path / "router.json5", {CERT_DIR: f"{certs}/"})
    listen = ("--listen", f"{public}#tls_handshake_timeout_ms=1000", "--listen", operator)
    estop_config = rewrite(DEPLOY / "zenoh-estop-tls.json5", tmp_path / "estop.json5", {
        f"{CERT_DIR}ca.pem": str(certs / "ca.pem"), f"{CERT_DIR}estop.": f"{certs / 'estop'}.", "tls/127.0.0.1:7449": operator})
    random_trajectory(robots, 1, np.random.default_rng(0)).save(tmp_path / "traj.json")
    children: list[Child] = []
    try:
        # 1024 open files: enough for this flood; the router warns that a larger one would block every listener.
        children.append(Child(["sh", "-c", 'ulimit -n 1024 && exec "$@"', "sh", *router_cmd("--config", str(router_config), *listen)]))
        children[0].wait_line("swarm router: listening on", 15)
        children[0].wait_line("swarm router: warning: 1024 open files allowed: a flood of that many connections blocks every listener", 5)
        children.append(Child([sys.executable, "-m", "swarm_cli.agent", f"--id=0-{robots - 1}", f"--trajectory={tmp_path / 'traj.json'}",
                               f"--run={run}", "--zenoh-config", str(client_config(tmp_path, certs, "gateway", public).config_file)]))
        with open_session(client_config(tmp_path, certs, "coordinator", public)) as observer:
            deadline = time.monotonic() + 30
            while len(alive_now(observer, alive_wildcard(run))) < robots:
                assert time.monotonic() < deadline and children[1].proc.poll() is None, children[1].stderr
                time.sleep(0.1)
        assert tls_handshake_ok(port, certs, "coordinator")
        with Flood(port, 300):
            time.sleep(1.2)
            estop = subprocess.Popen([sys.executable, "-m", "swarm_cli.main", "estop", f"--run={run}", "--zenoh-config", str(estop_config),
                                      "--repeat-s=0", "--ack-timeout=0.5", "--json"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     text=True, env=ENV)
            jammed = not tls_handshake_ok(port, certs, "coordinator")
            out, err = estop.communicate(timeout=60)
        assert jammed, "the flood did not jam the public listener"
        assert estop.returncode == 0, err
        assert json.loads(out.strip().splitlines()[-1])["agents"] == list(range(robots))
        settings = ZenohSettings("client", config_file=str(estop_config))
        assert len(stop_once(settings, run, robots, 2.0)) == robots  # the flood closed, its connections still queued
    finally:
        stop(children)


# -- mutual TLS and access control -------------------------------------------------------------------


@pytest.fixture
def tls_router(certs: Path, tmp_path: Path) -> Iterator[str]:
    """``swarm router`` with deploy/zenoh-router-tls-acl.json5 (cert paths into ``certs``); yields its endpoint."""
    endpoint = f"tls/127.0.0.1:{free_tcp_port()}"
    config = rewrite(DEPLOY / "zenoh-router-tls-acl.json5", tmp_path / "router.json5", {CERT_DIR: f"{certs}/"})
    router = Child(router_cmd("--config", str(config), "--listen", endpoint))
    try:
        router.wait_line("swarm router: listening on", 15)
        yield endpoint
    finally:
        stop([router])


def _statuses(inbox: queue.Queue[tuple[str, bytes]], wait_s: float, until_done: bool = False) -> list[Status]:
    """Status messages arriving within ``wait_s`` seconds (sooner once a 'done' came, if ``until_done``)."""
    got: list[Status] = []
    deadline = time.monotonic() + wait_s
    while (left := deadline - time.monotonic()) > 0:
        try:
            _, payload = inbox.get(timeout=left)
        except queue.Empty:
            break
        got.append(decode(payload, Status))
        if until_done and got[-1].state == "done":
            break
    return got


def test_acl_only_the_coordinator_commands_the_agent(certs: Path, tmp_path: Path, tls_router: str) -> None:
    """A real agent with the gateway identity obeys the coordinator identity only (not the gateway, estop or intruder ones)."""
    run = f"acl{uuid.uuid4().hex[:8]}"
    gateway_cfg = client_config(tmp_path, certs, "gateway", tls_router)
    agent_cmd = [sys.executable, "-m", "swarm_cli.agent", "--id", "0", "--ids", "0", "--run", run,
                 "--zenoh-config", str(gateway_cfg.config_file), "--pose", "0,0,0", "--motion-time", "0.05"]  # says 'accepted' too
    children: list[Child] = []
    try:
        with (
            open_session(client_config(tmp_path, certs, "coordinator", tls_router)) as coord,
            open_session(client_config(tmp_path, certs, "intruder", tls_router)) as intruder,
            open_session(client_config(tmp_path, certs, "estop", tls_router)) as estop,
            open_session(gateway_cfg) as gateway,
        ):
            _sub, statuses = subscribe_queue(coord, robot_key(run, 0, "status"))
            _isub, intruder_inbox = subscribe_queue(intruder, f"swarm/{run}/**")
            _esub, estop_inbox = subscribe_queue(estop, f"swarm/{run}/**")
            alive: queue.Queue[tuple[str, bool]] = queue.Queue()
            watch_liveliness(coord, alive_key(run, 0), lambda key, up: alive.put((key, up)))
            children.append(Child(agent_cmd))
            assert alive.get(timeout=20) == (alive_key(run, 0), True), "the agent's token never reached the coordinator"
            _token = declare_token(coord, coord_alive_key(run, 9))  # the coordinator of epoch 9
            time.sleep(0.3)

            # Neither a certificate of the same CA with another name, nor the gateway identity, nor
            # the estop identity (it may only stop) gets a command through: no Status at all for 2 s.
            for session, step in ((intruder, 5), (gateway, 6), (estop, 7)):
                cmd = MotionCommand(run=run, step=step, robot=0, config=1, turn_rad=0.1, drive_m=0.05, epoch=9)
                publish(session, message_key(cmd), encode(cmd))
            assert _statuses(statuses, 2.0) == []

            # The coordinator's step 1 is the first command the agent executes (had step 5 or 6
            # run, step 1 would be refused as stale; had step 1 run before, no 'accepted').
            cmd = MotionCommand(run=run, step=1, robot=0, config=1, turn_rad=0.1, drive_m=0.05, epoch=9)
            publish(coord, message_key(cmd), encode(cmd))
            got = _statuses(statuses, 10.0, until_done=True)
            assert [(s.step, s.state) for s in got] == [(1, "accepted"), (1, "done")], got

            # Neither the intruder nor the estop identity received anything from anyone (only its own
            # command, delivered locally: the estop identity hears acknowledgements of stops only).
            time.sleep(0.2)
            for inbox in (intruder_inbox, estop_inbox):
                keys = set()
                while not inbox.empty():
                    keys.add(inbox.get()[0])
                assert keys == {robot_key(run, 0, "cmd")}
            assert children[0].proc.poll() is None, children[0].stderr
    finally:
        stop(children)


def test_mtls_refuses_clients_without_a_certificate_of_the_ca(certs: Path, tmp_path: Path, tls_router: str) -> None:
    other = make_certs(tmp_path / "other-ca", "coordinator")  # right name, wrong CA
    refused = {
        "certificate of another CA": client_config(tmp_path, Path(other["out"]), "coordinator", tls_router, ca=certs / "ca.pem"),
        "no client certificate": client_config(tmp_path, certs, "coordinator", tls_router, mtls=False),
        "plain tcp": ZenohSettings("client", connect=(tls_router.replace("tls/", "tcp/"),)),
    }
    for label, settings in refused.items():
        with pytest.raises(ConnectionError):
            with open_session(settings):
                pytest.fail(f"{label}: the session opened")
    # A client that trusts another CA does not accept the router's certificate either.
    with pytest.raises(ConnectionError):
        with open_session(client_config(tmp_path, Path(other["out"]), "coordinator", tls_router)):
            pass
    with open_session(client_config(tmp_path, certs, "coordinator", tls_router)) as session:
        assert session.info.routers_zid()


def _broken_certs(certs: Path, tmp: Path) -> dict[str, tuple[Path, str]]:
    """A copy of the gateway's certificate and key per fault; the message each must give."""
    pem, key = (certs / "gateway.pem").read_text(), (certs / "gateway.key").read_text()
    lines = pem.splitlines()
    cases = {
        "corrupted certificate": ("\n".join(lines[:3] + lines[4:]), key, "the certificate is corrupted"),  # a base64 line lost
        "truncated certificate": (pem[: len(pem) * 2 // 3], key, "the certificate is corrupted or truncated"),
        "truncated key": (pem, key[: len(key) // 2], "the private key is corrupted or truncated"),
        "key of another host": (pem, (certs / "coordinator.key").read_text(), "is not the key of connect_certificate"),
        "a key for the certificate": (key, key, "no PEM certificate in it"),
        "empty key": (pem, "", "the file is empty"),
    }
    out = {}
    for label, (cert_text, key_text, message) in cases.items():
        folder = tmp / label.replace(" ", "-")
        folder.mkdir()
        shutil.copy(certs / "ca.pem", folder / "ca.pem")
        (folder / "gateway.pem").write_text(cert_text)
        (folder / "gateway.key").write_text(key_text)
        out[label] = folder, message
    return out


def test_broken_certificate_or_key_files_are_named_before_connecting(certs: Path, tmp_path: Path) -> None:
    """Each broken file gives one line naming the config field, the file and what is wrong (not "Unable to connect",
    which a dead router gives); a dead TLS router gives no Rust source path."""
    for label, (folder, message) in _broken_certs(certs, tmp_path).items():
        settings = client_config(tmp_path, folder, "gateway", "tls/127.0.0.1:9")
        proc = subprocess.run([sys.executable, "-m", "swarm_cli.main", "estop", "--run=lab", f"--zenoh-config={settings.config_file}"],
                              capture_output=True, text=True, timeout=60, env=ENV)
        err = proc.stderr
        assert proc.returncode == 2 and message in err and str(folder) in err and "Unable to connect" not in err, (label, err)
        assert "transport/link/tls/" in err and len(err.strip().splitlines()) == 1, (label, err)
    settings = client_config(tmp_path, certs, "gateway", f"tls/127.0.0.1:{free_tcp_port()}")  # good files, no router
    proc = subprocess.run([sys.executable, "-m", "swarm_cli.main", "estop", "--run=lab", f"--zenoh-config={settings.config_file}"],
                          capture_output=True, text=True, timeout=60, env=ENV)
    assert proc.returncode == 2 and "the router is down, unreachable, or refused them" in proc.stderr, proc.stderr
    assert ".rs:" not in proc.stderr, proc.stderr


# -- network namespaces ------------------------------------------------------------------------------


def _ip(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(["ip", *args], capture_output=True, text=True, timeout=10)


def test_netns_gateway_and_coordinator_in_separate_namespaces(tmp_path: Path) -> None:
    """Two namespaces, each joined to the root namespace by a veth pair and to nothing else; the
    router (root namespace) listens on both veth addresses with mutual TLS + access control, and a
    message crosses from the gateway namespace to the coordinator namespace and back."""
    if os.geteuid() != 0 or shutil.which("ip") is None:
        pytest.skip("network namespaces need root and the ip command")
    tag, subnet = os.getpid() % 100000, os.getpid() % 250 + 1
    spaces = {  # role: (namespace, root-side veth, namespace-side veth, router address, namespace address)
        "gateway": (f"swarm-g{tag}", f"swg{tag}r", f"swg{tag}n", f"10.213.{subnet}.1", f"10.213.{subnet}.2"),
        "coordinator": (f"swarm-c{tag}", f"swc{tag}r", f"swc{tag}n", f"10.214.{subnet}.1", f"10.214.{subnet}.2"),
    }
    made: list[tuple[str, ...]] = []
    children: list[Child] = []
    try:
        for ns, root_if, ns_if, router_ip, ns_ip in spaces.values():
            added = _ip("netns", "add", ns)
            if added.returncode != 0:
                pytest.skip(f"cannot create a network namespace: {added.stderr.strip()}")
            made.append(("netns", ns))
            for step in (("link", "add", root_if, "type", "veth", "peer", "name", ns_if),
                         ("link", "set", ns_if, "netns", ns),
                         ("addr", "add", f"{router_ip}/30", "dev", root_if),
                         ("link", "set", root_if, "up"),
                         ("-n", ns, "addr", "add", f"{ns_ip}/30", "dev", ns_if),
                         ("-n", ns, "link", "set", ns_if, "up")):
                done = _ip(*step)
                if done.returncode != 0:
                    pytest.skip(f"cannot set up veth pairs (ip {' '.join(step)}): {done.stderr.strip()}")
                if step[0] == "link" and step[1] == "add":
                    made.append(("link", root_if))
        g_ns, c_ns = spaces["gateway"][0], spaces["coordinator"][0]
        assert _ip("-n", g_ns, "route", "get", spaces["coordinator"][4]).returncode != 0, "the namespaces reach each other directly"

        port = free_tcp_port()
        certs = tmp_path / "certs"
        make_certs(certs, f"router={spaces['gateway'][3]},{spaces['coordinator'][3]}", "coordinator", "gateway")
        config = rewrite(DEPLOY / "zenoh-router-tls-acl.json5", tmp_path / "router.json5", {CERT_DIR: f"{certs}/"})
        router = Child(router_cmd("--config", str(config), *(f"--listen=tls/{s[3]}:{port}" for s in spaces.values())))
        children.append(router)
        router.wait_line("swarm router: listening on", 15)
        cmd_key, status_key = robot_key("netns", 0, "cmd"), robot_key("netns", 0, "status")
        gw = client_config(tmp_path, certs, "gateway", f"tls/{spaces['gateway'][3]}:{port}")
        co = client_config(tmp_path, certs, "coordinator", f"tls/{spaces['coordinator'][3]}:{port}")
        gateway = Child(side_cmd(gw, cmd_key, status_key, "gateway", ("ip", "netns", "exec", g_ns)))
        coordinator = Child(side_cmd(co, status_key, cmd_key, "coordinator", ("ip", "netns", "exec", c_ns)))
        children += [gateway, coordinator]
        for child, other in ((gateway, "coordinator"), (coordinator, "gateway")):
            code, out = child.finish(30)
            assert code == 0 and json.loads(out)["received"] == f"hello from {other}", child.stderr
    finally:
        stop(children)
        for kind, name in reversed(made):
            _ip(kind, "del", name)


@pytest.mark.parametrize("config_file", [None, "zenoh-router.json5"])
def test_every_session_waits_for_a_full_queue_before_zenoh_drops_a_sample(config_file: str | None) -> None:
    """Zenoh's default 1 ms before dropping a sample on a full transmit queue lost answers on a busy host;
    every session the runtime opens, from a deploy file or not, waits DROP_WAIT_US."""
    settings = ZenohSettings("router", listen=("tcp/127.0.0.1:0",), config_file=None if config_file is None else str(DEPLOY / config_file))
    drop = json.loads(settings.to_config().get_json("transport/link/tx/queue/congestion_control/drop"))
    assert drop["wait_before_drop"] == DROP_WAIT_US > 1000
