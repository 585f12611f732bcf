"""Processes of a distributed run on this host: robot agents, robot emulators and gateway links.

Each is started as its own Python process from its spec (``inchworm.specs``, ``inchworm.spawn.Spawned``: the
process runs what the ``swarm`` command of that kind runs) and stopped by its own pid (``stop_all``). ``swarm
launch``, the runtime and fault benchmarks and the tests start them through these functions.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import msgspec
import numpy as np

from inchworm.spawn import Spawned
from inchworm.specs import AgentHostSpec, EmulatorSpec, LinkSpec, PortProcessSpec
from runtime.errors import OptionError, SwarmInputError
from runtime.gateway.config import GatewayConfig, Limits, Port
from runtime.models.trajectory import Trajectory
from runtime.wire.keys import coord_key, estop_key, robot_wildcard
from runtime.wire.messages import CommandLimits, EmergencyStop, MessageError, MotionCommand, ObserveRequest, decode
from runtime.wire.transport import subscribe

if TYPE_CHECKING:
    import zenoh

GRACE_S = 3.0  # s a child gets after SIGTERM before SIGKILL
ONE_PER_PROCESS_UP_TO = 50  # robots: larger swarms share processes by default
AGENTS_PER_PROCESS = 50  # at most, when they share


def agents_per_process(n: int, requested: int | None) -> int:
    """Robots per agent process for a swarm of ``n``: ``requested`` (``--agents-per-process``), or the default."""
    if requested is None:
        if n <= ONE_PER_PROCESS_UP_TO:
            return 1
        processes = -(-n // AGENTS_PER_PROCESS)
        return -(-n // processes)  # balanced: 60 robots -> 2 processes of 30
    if requested < 1:
        raise OptionError("agents_per_process", f"must be >= 1, got {requested}")
    return requested


def start_agents(
    traj: Trajectory, base: AgentHostSpec, procs: list[subprocess.Popen[Any]] | None = None, per_process: int = 1,
    traj_file: Path | None = None, **popen_kwargs: Any,
) -> list[subprocess.Popen[Any]]:
    """Agent processes for the robots of ``traj``, appended to ``procs`` as each starts: one per robot (its initial true
    pose in its spec), or with ``per_process`` > 1 one per that many robots (poses from ``traj_file``, ``traj`` saved).
    ``base`` holds what every one shares (run, hub, seed, model, driver, ...); its robots are filled in. Pass your own
    ``procs`` list so that the ones already started can be stopped if a later start fails.
    """
    procs = [] if procs is None else procs
    ids = tuple(int(i) for i in traj.ids)
    if per_process == 1:
        for robot, pose in zip(ids, traj.initial_poses, strict=True):
            spec = msgspec.structs.replace(base, robots=(robot,), run_robots=ids, pose=(float(pose[0]), float(pose[1]), float(pose[2])))
            procs.append(Spawned(spec, **popen_kwargs))
        return procs
    if traj_file is None:
        raise ValueError("start_agents needs traj_file to host several agents per process")
    for k in range(0, traj.n, per_process):
        procs.append(Spawned(msgspec.structs.replace(base, robots=ids[k:k + per_process], run_robots=ids, trajectory=str(traj_file)),
                             **popen_kwargs))
    return procs


def stop_all(procs: Sequence[subprocess.Popen[Any]], grace_s: float = GRACE_S) -> None:
    """SIGTERM every child still running, SIGKILL those still running after ``grace_s``; reap all."""
    for p in procs:
        if p.poll() is None:
            try:
                p.send_signal(signal.SIGTERM)
            except ProcessLookupError:
                pass
    deadline = time.monotonic() + grace_s
    for p in procs:
        try:
            p.wait(timeout=max(0.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


AGENT_ERROR = "swarm agent: error: "  # how an agent process that exits 2 (bad input) says why (swarm_cli.entry)


class AgentErrors:
    """Forwards the agent processes' stderr to ours, keeping back their ``swarm agent: error:`` line: an agent that
    exits 2 (its driver failed to start, ...) ends the run with that line once (``failure``), not one per agent."""

    def __init__(self) -> None:
        self._lines: dict[int, str] = {}  # pid -> the error line (without the prefix)
        self._reported: set[int] = set()
        self._threads: dict[int, threading.Thread] = {}
        self._lock = threading.Lock()

    def popen_kwargs(self) -> dict[str, Any]:
        """What ``subprocess.Popen`` needs for ``watch`` (stderr piped, text)."""
        return {"stderr": subprocess.PIPE, "text": True, "errors": "replace"}

    def watch(self, procs: Sequence[subprocess.Popen[str]]) -> None:
        """Start forwarding the stderr of ``procs`` (started with ``popen_kwargs``; others are left alone)."""
        for p in procs:
            if p.stderr is not None and p.pid not in self._threads:
                thread = threading.Thread(target=self._forward, args=(p,), name=f"agent-stderr-{p.pid}", daemon=True)
                self._threads[p.pid] = thread
                thread.start()

    def _forward(self, proc: subprocess.Popen[str]) -> None:
        assert proc.stderr is not None
        for line in proc.stderr:
            if line.startswith(AGENT_ERROR):
                with self._lock:
                    self._lines.setdefault(proc.pid, line[len(AGENT_ERROR):].rstrip("\n"))
                continue
            sys.stderr.write(line)
            sys.stderr.flush()

    def failure(self, procs: Sequence[subprocess.Popen[Any]]) -> str | None:
        """The error line of the first of ``procs`` that exited with status 2 (bad input), else None; that line is
        then the caller's to report (``held`` no longer returns it)."""
        for p in procs:
            if p.poll() == 2:
                thread = self._threads.get(p.pid)
                if thread is not None:
                    thread.join(timeout=2.0)  # its last line is read by now (the pipe closed at its exit)
                with self._lock:
                    self._reported.add(p.pid)
                    return self._lines.get(p.pid, f"an agent process (pid {p.pid}) exited with status 2")
        return None

    def held(self) -> list[str]:
        """The error lines kept back and not reported by ``failure`` (an agent that failed after the run started),
        each as the agent printed it; call once the agents have ended."""
        for thread in self._threads.values():
            thread.join(timeout=2.0)
        with self._lock:
            return [AGENT_ERROR + line for pid, line in self._lines.items() if pid not in self._reported]


ROBOTS_PER_PORT = 5
GATEWAY_READY_S = 20.0  # s the robot emulator gets to open its ptys


def default_gateway(traj: Trajectory, margin_m: float = 1.0, robot_radius: float = Limits().robot_radius_m) -> GatewayConfig:
    """Ports ``radio0``, ``radio1``, ... of ``ROBOTS_PER_PORT`` robots each; the workspace is the
    trajectory's bounding box grown by ``margin_m``; the robots' body radius ``robot_radius`` (m);
    devices are filled in by the emulator."""
    ids = [int(i) for i in traj.ids]
    ports = tuple(Port(f"radio{k}", "emulated", tuple(ids[i:i + ROBOTS_PER_PORT]))
                  for k, i in enumerate(range(0, len(ids), ROBOTS_PER_PORT)))
    xy = np.concatenate([traj.initial_poses[:, :2], *traj.configurations])
    lo, hi = xy.min(axis=0) - margin_m, xy.max(axis=0) + margin_m
    return GatewayConfig(ports, limits=Limits(max_drive_m=CommandLimits().max_drive_m, workspace=(lo[0], lo[1], hi[0], hi[1]),
                                              robot_radius_m=robot_radius))


def start_emulator(spec: EmulatorSpec, procs: list[subprocess.Popen[Any]], **popen_kwargs: Any) -> Path:
    """Start the robot emulator ``spec`` (appended to ``procs``) and wait until it wrote its ``write_config``, the
    gateway config with its pty devices; returns that path."""
    if spec.write_config is None:
        raise ValueError("start_emulator needs the spec's write_config: the launcher waits for it")
    live = Path(spec.write_config)
    emulator = Spawned(spec, stdout=subprocess.DEVNULL, **popen_kwargs)
    procs.append(emulator)
    deadline = time.monotonic() + GATEWAY_READY_S
    while not live.exists():
        if emulator.poll() is not None:
            raise SwarmInputError(f"the robot emulator exited with status {emulator.returncode} before its ptys were ready")
        if time.monotonic() > deadline:
            raise SwarmInputError(f"the robot emulator did not write {live} within {GATEWAY_READY_S:.0f} s")
        time.sleep(0.02)
    return live


def start_gateway(gateway: GatewayConfig, tmp: Path, emulator: EmulatorSpec, procs: list[subprocess.Popen[Any]], links: bool = True,
                  **popen_kwargs: Any) -> Path:
    """Start the robot emulator ``emulator`` (its trajectory, seed, model, faults, run and hub; the config ``gateway`` is
    saved in ``tmp``) and, with ``links``, one link process per port (without: the agent processes run them,
    ``start_port_hosts``); the live gateway config (pty devices)."""
    if emulator.run_id is None:
        raise ValueError("start_gateway needs the emulator spec's run_id: the links serve that run")
    config = tmp / "gateway.json"
    gateway.save(config)
    live = start_emulator(msgspec.structs.replace(emulator, config=str(config), write_config=str(tmp / "gateway-live.json")), procs,
                          **popen_kwargs)
    for port in gateway.ports if links else ():
        procs.append(Spawned(LinkSpec(config=str(live), port=port.name, run_id=emulator.run_id, hub=emulator.hub,
                                      zenoh_config=emulator.zenoh_config), **popen_kwargs))
    return live


def start_port_hosts(traj: Trajectory, live: Path, base: AgentHostSpec, procs: list[subprocess.Popen[Any]], traj_file: Path,
                     **popen_kwargs: Any) -> dict[int, subprocess.Popen[Any]]:
    """The gateway PC's layout: one port process per port of the live gateway config ``live``, hosting the agents of
    the port's robots of ``traj`` (driver ``gateway``) and the port's link; robot -> its process. ``base`` holds what
    the agents share (run, hub, seed, model, ...)."""
    ids, run_robots = tuple(int(i) for i in traj.ids), {int(i) for i in traj.ids}
    shared = {**msgspec.structs.asdict(base), "run_robots": ids, "trajectory": str(traj_file), "driver": "gateway",
              "gateway_config": str(live)}
    hosts: dict[int, subprocess.Popen[Any]] = {}
    for port in GatewayConfig.load(live).ports:
        robots = tuple(r for r in port.robots if r in run_robots)
        if not robots:
            continue
        procs.append(Spawned(PortProcessSpec(**{**shared, "robots": robots}), **popen_kwargs))
        hosts.update((r, procs[-1]) for r in robots)
    return hosts


class RobotKiller:
    """``--kill-robot``: SIGKILL robot ``robot``'s agent process at the first command of ``step``, then time
    the coordinator's targeted ``EmergencyStop`` (wall clock, ns; all processes are on this host). Killers of robots
    hosted by one process share ``killed`` (pid -> when it was killed): the times count from the process's death."""

    def __init__(self, session: zenoh.Session, run_id: str, robot: int, step: int, process: subprocess.Popen[Any],
                 killed: dict[int, int] | None = None) -> None:
        self.robot, self.step, self.process = robot, step, process
        self._killed = {} if killed is None else killed
        self.killed_ns: int | None = None
        self.stop_stamp_ns: int | None = None
        self.stop_heard_ns: int | None = None
        self._subs = [subscribe(session, robot_wildcard(run_id, "cmd"), self._on_command),
                      subscribe(session, estop_key(run_id), self._on_estop)]

    def _on_command(self, key: str, payload: bytes) -> None:
        if self.killed_ns is not None:
            return
        try:
            cmd = decode(payload, MotionCommand)
        except MessageError:
            return
        if cmd.step >= self.step:
            if self.process.pid not in self._killed and self.process.poll() is None:
                self.process.send_signal(signal.SIGKILL)
                self._killed[self.process.pid] = time.time_ns()
            self.killed_ns = self._killed.get(self.process.pid)

    def _on_estop(self, key: str, payload: bytes) -> None:
        heard = time.time_ns()
        try:
            stop = decode(payload, EmergencyStop)
        except MessageError:
            return
        if self.robot in stop.robots and self.stop_heard_ns is None:
            self.stop_stamp_ns, self.stop_heard_ns = stop.stamp_ns, heard

    def report(self) -> dict[str, float | None] | None:
        """``{"robot", "step", "detect_ms", "estop_ms"}`` once the agent was killed (the times None if no stop came)."""
        for sub in self._subs:
            sub.undeclare()
        killed_ns = self.killed_ns
        if killed_ns is None:
            return None

        def ms(t: int | None) -> float | None:
            return None if t is None else round((t - killed_ns) / 1e6, 3)

        return {"robot": self.robot, "step": self.step, "detect_ms": ms(self.stop_stamp_ns), "estop_ms": ms(self.stop_heard_ns)}


class CoordinatorKiller:
    """``--kill-coordinator``: SIGKILL the coordinator at its first command of ``step``, then time the takeover: the
    first command or observation request of another epoch (wall clock, ns; all processes are on this host)."""

    def __init__(self, session: zenoh.Session, run_id: str, step: int, process: subprocess.Popen[Any]) -> None:
        self.step, self.process = step, process
        self.epoch: int | None = None
        self.killed_ns: int | None = None
        self.taken_ns: int | None = None
        self._subs = [subscribe(session, robot_wildcard(run_id, leaf), self._on_message) for leaf in ("cmd", "observe")]

    def _on_message(self, key: str, payload: bytes) -> None:
        heard = time.time_ns()
        try:
            msg = decode(payload, MotionCommand) if key.endswith("/cmd") else decode(payload, ObserveRequest)
        except MessageError:
            return
        if self.killed_ns is None:
            if isinstance(msg, MotionCommand) and msg.step >= self.step and self.process.poll() is None:
                self.process.send_signal(signal.SIGKILL)
                self.killed_ns, self.epoch = time.time_ns(), msg.epoch
        elif self.taken_ns is None and msg.epoch != self.epoch:
            self.taken_ns = heard

    def report(self) -> dict[str, float | None] | None:
        """``{"step", "takeover_ms"}`` once the coordinator was killed (``takeover_ms`` None if nobody took over)."""
        for sub in self._subs:
            sub.undeclare()
        if self.killed_ns is None:
            return None
        taken = None if self.taken_ns is None else round((self.taken_ns - self.killed_ns) / 1e6, 3)
        return {"step": self.step, "takeover_ms": taken}


class ProcessStaller:
    """``--stall-coordinator`` / ``--stall-link``: SIGSTOP ``process`` at the first command of ``step`` and SIGCONT it
    ``seconds`` later (a process swapped out or hung that comes back), as a user would with ``kill -STOP`` / ``-CONT``."""

    def __init__(self, session: zenoh.Session, run_id: str, step: int, seconds: float, process: subprocess.Popen[Any]) -> None:
        self.step, self.seconds, self.process = step, seconds, process
        self.stopped_ns: int | None = None
        self.resumed_ns: int | None = None
        self._timer: threading.Timer | None = None
        self._sub = subscribe(session, robot_wildcard(run_id, "cmd"), self._on_command)

    def _on_command(self, key: str, payload: bytes) -> None:
        if self.stopped_ns is not None:
            return
        try:
            cmd = decode(payload, MotionCommand)
        except MessageError:
            return
        if cmd.step >= self.step and self.process.poll() is None:
            self.process.send_signal(signal.SIGSTOP)
            self.stopped_ns = time.time_ns()
            self._timer = threading.Timer(self.seconds, self.resume)
            self._timer.daemon = True
            self._timer.start()

    def resume(self) -> None:
        """SIGCONT the process (at once if the stall is still on; idempotent)."""
        if self.stopped_ns is not None and self.resumed_ns is None:
            self.resumed_ns = time.time_ns()
            if self.process.poll() is None:
                self.process.send_signal(signal.SIGCONT)

    def report(self) -> dict[str, float] | None:
        """``{"step", "stall_s"}`` once the process was stalled (``stall_s`` as measured), else None; resumes it if still stopped."""
        self._sub.undeclare()
        if self._timer is not None:
            self._timer.cancel()
        self.resume()
        if self.stopped_ns is None or self.resumed_ns is None:
            return None
        return {"step": self.step, "stall_s": round((self.resumed_ns - self.stopped_ns) / 1e9, 3)}


def wait_for_standby(session: zenoh.Session, run_id: str, standby: subprocess.Popen[Any], timeout_s: float = 60.0) -> None:
    """Until the standby coordinator follows the run's checkpoints (its subscription reached the hub), so it sees
    the coordinator that starts next from its first checkpoint on."""
    probe = session.declare_publisher(coord_key(run_id, "checkpoint"))  # never published on
    try:
        deadline = time.monotonic() + timeout_s
        while not cast("zenoh.MatchingStatus", probe.matching_status).matching:  # zenoh's stub says bool
            if standby.poll() is not None:
                raise SwarmInputError(f"the standby coordinator exited with status {standby.returncode} before it was ready")
            if time.monotonic() > deadline:
                raise SwarmInputError(f"the standby coordinator was not ready within {timeout_s:.0f} s")
            time.sleep(0.01)
    finally:
        probe.undeclare()
