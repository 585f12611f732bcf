"""A run spread over several hosts through Zenoh routers (deploy/README.md, "Many agent hosts"),
with network namespaces as hosts: two agent hosts and a coordinator host on one bridge, each
host with its own ``swarm router``; the agent hosts' routers connect to the coordinator host's
(deploy/zenoh-agent-host.json5) and the agents connect to their own host's router over that
host's loopback. The run's result is identical to a single-host ``swarm launch``.

Needs root and the ``ip`` command (skipped otherwise). Private 10.216.x addresses on a bridge of
this test; multicast scouting off; every process is stopped by its pid, every namespace, veth
and bridge deleted at the end.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from runtime.models.trajectory import Trajectory, random_trajectory
from runtime.wire.transport import free_tcp_port

REPO = Path(__file__).resolve().parents[2]
ENV = {**os.environ, "PYTHONPATH": str(REPO)}


def _ip(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(["ip", *args], capture_output=True, text=True, timeout=10)


class Hosts:
    """Namespaces ``name -> address`` joined by one bridge of the root namespace (deleted by ``remove``)."""

    def __init__(self, names: list[str]) -> None:
        tag, subnet = os.getpid() % 100000, os.getpid() % 250 + 1
        self.bridge = f"swb{tag}"
        self.made: list[tuple[str, str]] = []
        self.ns: dict[str, str] = {}
        self.address: dict[str, str] = {}
        self._run("link", "add", self.bridge, "type", "bridge")
        self.made.append(("link", self.bridge))
        self._run("link", "set", self.bridge, "up")
        for k, name in enumerate(names, start=1):
            ns, root_if, ns_if, address = f"swarm-{name}{tag}", f"sw{tag}{k}r", f"sw{tag}{k}n", f"10.216.{subnet}.{k}"
            self._run("netns", "add", ns)
            self.made.append(("netns", ns))
            self._run("link", "add", root_if, "type", "veth", "peer", "name", ns_if)
            self.made.append(("link", root_if))
            for step in (("link", "set", ns_if, "netns", ns), ("link", "set", root_if, "master", self.bridge),
                         ("link", "set", root_if, "up"), ("-n", ns, "addr", "add", f"{address}/24", "dev", ns_if),
                         ("-n", ns, "link", "set", ns_if, "up"), ("-n", ns, "link", "set", "lo", "up")):
                self._run(*step)
            self.ns[name], self.address[name] = ns, address

    def _run(self, *args: str) -> None:
        done = _ip(*args)
        if done.returncode != 0:
            self.remove()
            pytest.skip(f"cannot set up the namespaces (ip {' '.join(args)}): {done.stderr.strip()}")

    def start(self, name: str, cmd: list[str], log: Path) -> subprocess.Popen:
        return subprocess.Popen(["ip", "netns", "exec", self.ns[name], *cmd], cwd=REPO, env=ENV, stdout=subprocess.PIPE,
                                stderr=log.open("w"), text=True)

    def remove(self) -> None:
        for kind, name in reversed(self.made):
            _ip(kind, "del", name)
        self.made.clear()


def _stop(procs: list[subprocess.Popen]) -> None:
    for p in procs:
        if p.poll() is None:
            os.kill(p.pid, signal.SIGTERM)
    deadline = time.monotonic() + 5.0
    for p in procs:
        try:
            p.wait(timeout=max(0.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            os.kill(p.pid, signal.SIGKILL)
            p.wait()


def _wait_for(log: Path, text: str, proc: subprocess.Popen, timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while text not in log.read_text():
        assert proc.poll() is None and time.monotonic() < deadline, f"no {text!r} in {log}: {log.read_text()}"
        time.sleep(0.05)


def test_agents_on_two_hosts_and_the_coordinator_on_a_third_give_the_single_host_result(tmp_path):
    if os.geteuid() != 0 or shutil.which("ip") is None:
        pytest.skip("network namespaces need root and the ip command")
    traj_file = tmp_path / "traj.json"
    random_trajectory(6, 2, np.random.default_rng(11)).save(traj_file)
    seed, run = 5, f"multihost{os.getpid()}"

    single = tmp_path / "single.json"
    done = subprocess.run([sys.executable, "-m", "swarm_cli.main", "launch", f"--trajectory={traj_file}", f"--seed={seed}",
                           f"--result={single}", "--no-record", f"--out={tmp_path / 'single'}", "--agents-per-process=1"],
                          capture_output=True, text=True, timeout=300, cwd=REPO, env=ENV)
    assert done.returncode == 0, done.stderr

    hosts = Hosts(["coord", "a", "b"])
    procs: list[subprocess.Popen] = []
    try:
        port = free_tcp_port()
        coord_router = f"tcp/{hosts.address['coord']}:{port}"
        log = tmp_path / "router-coord.log"
        procs.append(hosts.start("coord", [sys.executable, "-m", "swarm_cli.router", f"--listen={coord_router}"], log))
        _wait_for(log, "listening on", procs[-1], 30)
        shipped = (REPO / "deploy" / "zenoh-agent-host.json5").read_text()
        agents = {"a": [["--id=0-2"]], "b": [["--id=3-4"], ["--id=5", "--pose=" + ",".join(map(repr, _pose(traj_file, 5)))]]}
        for name, groups in agents.items():  # host b: one process of two agents and one of a single agent
            config = tmp_path / f"router-{name}.json5"
            config.write_text(shipped.replace("COORDINATOR_PC:7447", f"{hosts.address['coord']}:{port}")
                              .replace("127.0.0.1:7447", f"127.0.0.1:{port}"))
            log = tmp_path / f"router-{name}.log"
            procs.append(hosts.start(name, [sys.executable, "-m", "swarm_cli.router", f"--config={config}"], log))
            _wait_for(log, "listening on", procs[-1], 30)
            for k, ids in enumerate(groups):
                procs.append(hosts.start(name, [sys.executable, "-m", "swarm_cli.agent", *ids, f"--trajectory={traj_file}",
                                                f"--run={run}", f"--hub=tcp/127.0.0.1:{port}", f"--seed={seed}"],
                                         tmp_path / f"agents-{name}{k}.log"))
        multi = tmp_path / "multi.json"
        coordinator = hosts.start("coord", [sys.executable, "-m", "swarm_cli.coordinator_cmd", f"--trajectory={traj_file}",
                                            f"--run={run}", f"--hub={coord_router}", f"--seed={seed}", f"--result={multi}",
                                            "--no-record", "--start-timeout=60"], tmp_path / "coordinator.log")
        procs.append(coordinator)
        code = coordinator.wait(timeout=240)
        assert code == 0, (tmp_path / "coordinator.log").read_text()
        assert multi.read_text() == single.read_text()  # bit for bit: same plans, estimates and truths
        assert all(p.poll() is None for p in procs[:-1]), "a router or agent process exited during the run"
    finally:
        _stop(procs)
        hosts.remove()


def _pose(traj_file: Path, robot: int) -> list[float]:
    traj = Trajectory.load(traj_file)
    return [float(v) for v in traj.initial_poses[list(traj.ids).index(robot)]]
