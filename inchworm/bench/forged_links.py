"""Forged ``LinkRequest``s during and after a gateway run (``swarm bench faults``, ``"forged_link_requests"``).

The layout of a lab's gateway PC with the link processes apart (``swarm link`` per port, one
``swarm agent --driver gateway`` per robot, all over Zenoh), robots emulated on ptys, a
``swarm coordinator``. A client allowed on ``linkreq`` (what the gateway identity may do under
deploy/'s access control) forges, for every coordinator command it sees: the robot's next step
with a made-up start pose and a 0.5 m drive, the current step with another motion, a step 100
ahead, and the step before again with another motion. Once the coordinator has exited (no
coordinator alive), it sends every robot ``AFTER_RUN`` more: copies of the coordinator's last
command for the following steps, and 0.5 m moves.

``executed`` counts the motions the robots began (the emulator's ``accepted`` events) that no
coordinator command asked for: another robot, step, turn or drive than a ``MotionCommand`` the
coordinator published, or any motion after it exited. It must be 0.
"""

from __future__ import annotations

import json
import subprocess
import tempfile
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from inchworm.processes import default_gateway, start_agents, start_gateway, stop_all
from inchworm.spawn import Spawned
from inchworm.specs import AgentHostSpec, CoordinatorSpec, EmulatorSpec
from runtime.models.config import ModelConfig
from runtime.models.trajectory import body_spacing, random_trajectory
from runtime.wire.keys import robot_key, robot_wildcard
from runtime.wire.messages import LinkRequest, MessageError, MotionCommand, decode, encode
from runtime.wire.transport import free_tcp_port, loopback_hub, open_session, publish, subscribe

if TYPE_CHECKING:
    import zenoh

AFTER_RUN = 4  # forgeries per robot once the coordinator is gone
SETTLE_S = 2.5  # after the last forgery: longer than the link's hold (the retry budget, 1.6 s) and a 0.5 m motion's emulation


def _f32(x: float) -> float:
    return float(np.float32(x))


class Forger:
    """Publishes forgeries for every coordinator command it hears on run ``run_id`` (Zenoh thread)."""

    def __init__(self, session: zenoh.Session, run_id: str) -> None:
        self.session, self.run_id = session, run_id
        self.commanded: dict[tuple[int, int], tuple[float, float]] = {}  # (robot, step) -> (turn, drive) as on the wire
        self.last: dict[int, MotionCommand] = {}
        self.sent = 0
        self._lock = threading.Lock()
        self._sub = subscribe(session, robot_wildcard(run_id, "cmd"), self._on_command)

    def _send(self, **fields: Any) -> None:
        req = LinkRequest(run=self.run_id, kind="command", **fields)
        publish(self.session, robot_key(self.run_id, req.robot, "linkreq"), encode(req))
        with self._lock:
            self.sent += 1

    def _on_command(self, key: str, payload: bytes) -> None:
        try:
            cmd = decode(payload, MotionCommand, key=key)
        except MessageError:
            return
        with self._lock:
            if (cmd.robot, cmd.step) in self.commanded:
                return  # a re-send: forged once per step
            self.commanded[(cmd.robot, cmd.step)] = (_f32(cmd.turn_rad), _f32(cmd.drive_m))
            self.last[cmd.robot] = cmd
        r, s, e = cmd.robot, cmd.step, cmd.epoch
        self._send(robot=r, step=s + 1, turn_rad=0.0, drive_m=0.5, start_pose=[0.0, 0.0, 0.0], epoch=e)  # made-up start pose
        self._send(robot=r, step=s, turn_rad=cmd.turn_rad + 0.5, drive_m=0.5, epoch=e)  # the current step, another motion
        self._send(robot=r, step=s + 100, turn_rad=0.0, drive_m=0.5, epoch=e)  # a future step
        if s > 1:
            self._send(robot=r, step=s - 1, turn_rad=0.0, drive_m=0.5, epoch=e)  # a stale step

    def after_run(self) -> None:
        """No coordinator alive: copies of each robot's last command for the next steps, and 0.5 m moves."""
        self._sub.undeclare()
        for robot, cmd in sorted(self.last.items()):
            for k in range(1, AFTER_RUN + 1):
                motion = (cmd.turn_rad, cmd.drive_m) if k % 2 else (0.0, 0.5)
                self._send(robot=robot, step=cmd.step + k, turn_rad=motion[0], drive_m=motion[1], epoch=cmd.epoch)


def unasked_motions(events: Path, commanded: dict[tuple[int, int], tuple[float, float]], end_ns: int) -> int:
    """Motions the robots began (``accepted`` events) that no coordinator command asked for, or after ``end_ns``."""
    count = 0
    for line in events.read_text().splitlines() if events.exists() else ():
        try:
            row = json.loads(line)
        except json.JSONDecodeError:
            continue  # a line cut by the emulator's stop
        if row.get("event") != "accepted":
            continue
        asked = commanded.get((row["robot"], row["step"]))
        motion = (_f32(row["turn_rad"]), _f32(row["drive_m"]))
        count += asked is None or not np.allclose(motion, asked, rtol=1e-6, atol=1e-7) or row["time_ns"] > end_ns
    return count


def forged_link_requests(robots: int = 5, configs: int = 2, seed: int = 0) -> dict[str, int | bool]:
    """``{"sent", "executed", "completed"}``: forgeries sent, motions no coordinator asked for, the run exit 0."""
    traj = random_trajectory(robots, configs, np.random.default_rng(seed), **body_spacing(ModelConfig()))
    run_id = f"forged{seed}"
    port = free_tcp_port()
    hub_settings, member = loopback_hub(port)
    hub = f"tcp/127.0.0.1:{port}"
    procs: list[subprocess.Popen[Any]] = []
    with tempfile.TemporaryDirectory(prefix="swarm-bench-forged-") as tmp, open_session(hub_settings), \
            open_session(member) as session:
        folder = Path(tmp)
        traj_file, events = folder / "trajectory.json", folder / "events.jsonl"
        traj.save(traj_file)
        forger = Forger(session, run_id)
        try:
            emulator = EmulatorSpec(config="", trajectory=str(traj_file), seed=seed, events=str(events), hub=hub, run_id=run_id)
            live = start_gateway(default_gateway(traj), folder, emulator, procs, stderr=subprocess.DEVNULL)  # its stdout is taken already
            start_agents(traj, AgentHostSpec(run_id=run_id, robots=(), hub=hub, seed=seed, driver="gateway", gateway_config=str(live)), procs,
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            coordinator = Spawned(CoordinatorSpec(trajectory=str(traj_file), run_id=run_id, hub=hub, seed=seed, out=str(folder), no_record=True),
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            procs.append(coordinator)
            coordinator.wait(timeout=300)
            end_ns = time.time_ns()
            forger.after_run()
            time.sleep(SETTLE_S)
        finally:
            stop_all(procs)
        executed = unasked_motions(events, forger.commanded, end_ns)
    return {"sent": forger.sent, "executed": executed, "completed": coordinator.returncode == 0}


if __name__ == "__main__":  # python -m inchworm.bench.forged_links: one JSON line
    print(json.dumps(forged_link_requests()))
