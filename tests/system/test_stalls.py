"""Stalls judged right (docs/failure-model.md): a coordinator SIGSTOPped beyond its session lease, with and without a
standby (with one, through a relay that hands it the hub's tokens late once it is back); a run-wide stop heard by the
coordinator that took a run over; a link process SIGSTOPped past its robots' watchdog. Real processes on loopback and
real signals, each process stopped by its pid. The coordinators here run with a 2 s Zenoh lease (``--zenoh-config``),
so a 3.5 s stall loses their session as a 12 s one does by default (``swarm bench faults``, ``"coordinator_stall"``,
stalls them 12 s under ``swarm launch``)."""

from __future__ import annotations

import contextlib
import json
import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from coordinator.simulate import simulate
from inchworm.bench.faults import same_table
from inchworm.processes import start_agents, stop_all, wait_for_standby
from inchworm.specs import AgentHostSpec
from runtime.models.config import ModelConfig
from runtime.models.trajectory import random_trajectory
from runtime.wire.keys import coord_alive_key, estop_key, robot_wildcard
from runtime.wire.messages import EmergencyStop, MotionCommand, decode, encode, message_key
from runtime.wire.transport import open_loopback_hub, publish, subscribe, watch_liveliness
from tests.waiting import wait_for

REPO = Path(__file__).resolve().parents[2]
ENV = {**os.environ, "PYTHONPATH": str(REPO)}
SEED = 5


class SlowRelay:
    """A TCP relay on loopback from a coordinator to the hub that, once ``slow()`` was called, hands the hub's data on
    new connections ``hold_s`` late from their first liveliness token on (a congested link, a busy hub): the
    coordinator's session is back at once, the hub's tokens are not. ``close()`` ends it and its connections."""

    def __init__(self, hub: str, hold_s: float) -> None:
        self.hub_port, self.hold_s, self.slow_from = int(hub.rsplit(":", 1)[1]), hold_s, float("inf")
        self.server = socket.create_server(("127.0.0.1", 0))
        self.endpoint = f"tcp/127.0.0.1:{self.server.getsockname()[1]}"
        self.sockets: list[socket.socket] = []
        threading.Thread(target=self._accept, daemon=True).start()

    def slow(self) -> None:
        self.slow_from = time.monotonic()

    def _accept(self) -> None:
        with contextlib.suppress(OSError):
            while True:
                member, _ = self.server.accept()
                hub = socket.create_connection(("127.0.0.1", self.hub_port))
                self.sockets += [member, hub]
                held = time.monotonic() > self.slow_from
                threading.Thread(target=self._pump, args=(member, hub, False), daemon=True).start()
                threading.Thread(target=self._pump, args=(hub, member, held), daemon=True).start()

    def _pump(self, source: socket.socket, target: socket.socket, held: bool) -> None:
        until = None
        with contextlib.suppress(OSError):
            while data := source.recv(65536):
                if held and until is None and b"/alive/" in data:
                    until = time.monotonic() + self.hold_s
                if until is not None:
                    time.sleep(max(0.0, until - time.monotonic()))
                target.sendall(data)
        with contextlib.suppress(OSError):
            target.shutdown(socket.SHUT_WR)

    def close(self) -> None:
        for sock in (self.server, *self.sockets):
            sock.close()


class Run:
    """A hub (this process), 6 agents and the messages the test watches: commands, run-wide stops, coordinator tokens."""

    def __init__(self, tmp: Path, run_id: str) -> None:
        self.tmp, self.run_id = tmp, run_id
        self.traj = random_trajectory(6, 2, np.random.default_rng(SEED))
        self.traj_file = tmp / "traj.json"
        self.traj.save(self.traj_file)
        (tmp / "lease.json5").write_text("{ transport: { link: { tx: { lease: 2000, keep_alive: 4 } } } }")
        self.procs: list[subprocess.Popen] = []
        self.commands: list[tuple[float, MotionCommand]] = []
        self.stops: list[tuple[float, EmergencyStop]] = []
        self.gone: list[float] = []  # when a coordinator's token went

    def __enter__(self) -> Run:
        self.session, _, self.hub = open_loopback_hub()
        self.session.__enter__()
        r = self.run_id
        self._subs = [
            subscribe(self.session, robot_wildcard(r, "cmd"),
                      lambda key, payload: self.commands.append((time.monotonic(), decode(payload, MotionCommand)))),
            subscribe(self.session, estop_key(r),
                      lambda key, payload: self.stops.append((time.monotonic(), decode(payload, EmergencyStop)))),
            watch_liveliness(self.session, coord_alive_key(r), lambda key, alive: None if alive else self.gone.append(time.monotonic())),
        ]
        start_agents(self.traj, AgentHostSpec(run_id=r, robots=(), hub=self.hub, seed=SEED, motion_time=0.3), self.procs,
                     env=ENV, stderr=subprocess.DEVNULL)
        return self

    def __exit__(self, *exc) -> None:
        stop_all(self.procs)
        self.session.__exit__(*exc)

    def coordinator(self, *extra: str, hub: str | None = None) -> subprocess.Popen:
        proc = subprocess.Popen([sys.executable, "-m", "swarm_cli.coordinator_cmd", f"--trajectory={self.traj_file}", "--method=ref57",
                                 f"--run={self.run_id}", f"--hub={hub or self.hub}", f"--zenoh-config={self.tmp / 'lease.json5'}",
                                 f"--seed={SEED}", "--no-record", "--json", f"--out={self.tmp}", *extra],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=self.tmp, env=ENV)
        self.procs.append(proc)
        return proc

    def stall_at(self, proc: subprocess.Popen, step: int, seconds: float, before_resuming: Callable[[], object] = lambda: None) -> bool:
        """SIGSTOP ``proc`` once a command of ``step`` went out, SIGCONT it ``seconds`` later (``before_resuming()``
        first); whether the hub dropped a coordinator's token meanwhile (the stall outlasted its lease)."""
        wait_for(lambda: any(c.step >= step for _, c in self.commands), 60, f"step {step}")
        proc.send_signal(signal.SIGSTOP)
        stopped = time.monotonic()
        time.sleep(seconds)
        before_resuming()
        proc.send_signal(signal.SIGCONT)
        return any(t > stopped for t in self.gone)

    def reference(self):
        return simulate(self.traj, "ref57", ModelConfig(), seed=SEED)


def test_a_coordinator_stalled_beyond_its_lease_without_a_standby_goes_on_with_every_robot(tmp_path):
    """SIGSTOP 3.5 s, beyond its 2 s lease: the hub drops its session (its token goes) and every robot's token goes from
    its view; resumed, it declares none lost (they are all alive) and finishes the run as if nothing happened."""
    with Run(tmp_path, "stall") as run:
        coordinator = run.coordinator()
        assert run.stall_at(coordinator, 2, 3.5), "the stall did not outlast the coordinator's lease"
        out, err = coordinator.communicate(timeout=120)
    assert coordinator.returncode == 0, err[-3000:]
    summary = json.loads(out.strip().splitlines()[-1])
    assert summary["lost"] == [] and " lost (" not in err, err[-3000:]
    assert same_table(summary, run.reference())  # the fault-free run's table and P_f
    assert run.stops == []


def test_a_coordinator_stalled_beyond_its_lease_steps_down_and_the_standby_finishes_the_run(tmp_path):
    """With a standby: it takes the run over when the stalled coordinator's token goes; the stalled one, resumed, steps
    down (exit 4), declares no robot lost and stops nothing; the standby finishes the run with every robot.

    The stalled one reaches the hub through a relay that, after the stall, hands it the hub's tokens 0.5 s after its
    session is back (as a busy host does now and then: two test workers at once showed it). For that half second its
    view has no robot and no standby, and a liveliness query answers empty: it must wait for its view to settle, not
    declare the robots lost (a coordinator that judged a gone token at once did, in every run)."""
    with Run(tmp_path, "stallsb") as run, contextlib.closing(SlowRelay(run.hub, hold_s=0.5)) as relay:
        standby = run.coordinator("--standby")
        wait_for_standby(run.session, run.run_id, standby)
        coordinator = run.coordinator(hub=relay.endpoint)
        assert run.stall_at(coordinator, 2, 3.5, relay.slow), "the stall did not outlast the coordinator's lease"
        _, err = coordinator.communicate(timeout=60)
        out_standby, err_standby = standby.communicate(timeout=120)
    assert coordinator.returncode == 4 and "stepping down" in err, err[-3000:]
    assert " lost (" not in err, err[-3000:]
    assert standby.returncode == 0 and "takes over run" in err_standby, err_standby[-3000:]
    summary = json.loads(out_standby.strip().splitlines()[-1])
    assert summary["lost"] == [] and len(summary["configs"]) == 2
    assert same_table(summary, run.reference())
    assert run.stops == []  # nobody stopped the run, nor a robot


def test_the_coordinator_that_took_a_run_over_stops_commanding_on_a_run_wide_stop(tmp_path):
    """SIGKILL the coordinator; the standby takes over; ``swarm estop``'s run-wide stop then ends the standby's run
    (exit 3, naming who stopped it) and it sends no command after it."""
    with Run(tmp_path, "stopsb") as run:
        standby = run.coordinator("--standby")
        wait_for_standby(run.session, run.run_id, standby)
        coordinator = run.coordinator()
        wait_for(lambda: any(c.step >= 2 for _, c in run.commands), 60, "step 2")
        coordinator.send_signal(signal.SIGKILL)
        first = run.commands[-1][1].epoch
        wait_for(lambda: any(c.epoch != first for _, c in run.commands), 30, "the standby's first command")
        stop = EmergencyStop(run=run.run_id, step=0, source="swarm estop (test)", reason="operator")
        publish(run.session, message_key(stop), encode(stop))
        stopped = time.monotonic()
        _, err = standby.communicate(timeout=60)
    assert standby.returncode == 3 and "the run was stopped by swarm estop (test)" in err, err[-3000:]
    late = [c.step for t, c in run.commands if t > stopped + 0.5]
    assert late == [], late  # (a command already on its way when the stop went out may land just after it)


def test_a_link_stall_past_the_watchdog_reports_the_port_robots_lost_then_readmits_them(tmp_path):
    """``swarm launch --driver gateway --stall-link 2:3``: the first port's link process is SIGSTOPped 3 s, longer
    than the robots' 2 s watchdog, which stops them (the emulator's event log says so). A robot that refuses its next
    command (NO_HEARTBEAT: the command reached it before the link's first heartbeat did) gets no emergency stop and is
    re-admitted at the next configuration; either way the run completes with all 10 and nobody is stopped.

    Only the watchdogs that fired during the run count: once the coordinator's token is gone (the run over, its plots
    still being drawn) the links stop feeding every robot by design, so every watchdog fires 2 s later if the launcher
    has not stopped the emulator by then (a loaded machine)."""
    result, events = tmp_path / "result.json", tmp_path / "events.jsonl"
    proc = subprocess.run([sys.executable, "-m", "swarm_cli.main", "launch", "--driver=gateway", "-n=10", "--configs=3",
                           "--agents-per-process=5", "--motion-time=0.1", "--stall-link=2:3", "--no-record", f"--out={tmp_path}",
                           f"--result={result}", f"--emulator-events={events}", "--json"],
                          capture_output=True, text=True, cwd=tmp_path, env=ENV, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    summary, saved = json.loads(proc.stdout.strip().splitlines()[-1]), json.loads(result.read_text())
    assert summary["link_stall"]["step"] == 2 and summary["link_stall"]["stall_s"] >= 3.0
    log = [json.loads(line) for line in events.read_text().splitlines()]
    run_end = max(e["time_ns"] for e in log if e["event"] == "observed")  # the robots' last answer of the run
    starved = {e["robot"] for e in log if e["event"] == "heartbeat_timeout" and e["time_ns"] < run_end}
    assert starved and starved <= {0, 1, 2, 3, 4}, (starved, proc.stderr[-3000:])  # the stalled port's robots' watchdogs fired
    lost = {x["robot"] for x in saved["lost"]}
    assert lost <= starved and all("NO_HEARTBEAT" in x["reason"] for x in saved["lost"]), (saved["lost"], proc.stderr[-3000:])
    assert {x["robot"] for x in saved["rejoined"]} == lost
    assert sorted(saved["steps"][-1]["ids"]) == list(range(10))
    assert "dropping the liveliness token" not in proc.stderr, proc.stderr[-3000:]  # no agent gave its robot up
    assert "emergency stop sent" not in proc.stderr and not re.search(r"robot \d+: emergency stop", proc.stderr), proc.stderr[-3000:]
