"""What a recorded run says each robot was commanded, observed and (simulation) truly did, by robot and step.

``load_run_log`` reads an MCAP recording (``runtime.recording.mcap_log``) once and keeps
the executed commands (a ``MotionCommand`` whose ``Status`` says ``done``), the
``ObservationReport``s and the simulated truths (``TruthMessage``), each by (robot,
global step); a command or report sent again is the same message and is kept once.
Undecodable messages are skipped, as every reader of recordings does.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np

from runtime.errors import SwarmInputError
from runtime.recording.mcap_log import read_messages, recording_info
from runtime.wire.keys import KeyspaceError
from runtime.wire.messages import MessageError, MotionCommand, ObservationReport, Status, TruthMessage, decode, type_for_key


@dataclass
class RunLog:
    """One run's per-robot, per-step record (SI units: metres, radians)."""

    ids: list[int]
    commands: dict[tuple[int, int], tuple[float, float]] = field(default_factory=dict)  # (robot, step) -> (turn, drive), executed
    observations: dict[tuple[int, int], tuple[np.ndarray, np.ndarray, np.ndarray]] = field(default_factory=dict)
    truths: dict[tuple[int, int], np.ndarray] = field(default_factory=dict)  # (robot, step) -> true pose (simulation)
    report_ns: dict[tuple[int, int], int] = field(default_factory=dict)  # (robot, step) -> its ObservationReport's stamp_ns
    first_command_ns: dict[int, int] = field(default_factory=dict)  # step -> stamp_ns of its first MotionCommand

    def step_end_times(self) -> dict[tuple[int, int], float]:
        """When each robot's step ended (s since the Unix epoch, publishers' clocks): step s >= 1 when the robot
        reported its observations of s, step 0 when the first command of step 1 went out (nothing had moved)."""
        times = {key: ns / 1e9 for key, ns in self.report_ns.items()}
        if 1 in self.first_command_ns:
            times.update({(robot, 0): self.first_command_ns[1] / 1e9 for robot in self.ids})
        return times


def load_run_log(path: str | os.PathLike[str]) -> RunLog:
    """The ``RunLog`` of the recording ``path`` (``SwarmInputError`` if it is unreadable or holds no observations)."""
    info = recording_info(path)
    traj = (info.get("metadata", {}).get("run") or {}).get("trajectory")
    robots = traj.get("robots") if isinstance(traj, dict) else None
    ids: set[int] = {int(i) for i in robots} if isinstance(robots, list) else set()
    sent: dict[tuple[int, int], tuple[float, float]] = {}
    done: set[tuple[int, int]] = set()
    log = RunLog([])
    for topic, payload, _, _ in read_messages(path):
        try:
            kind = type_for_key(topic)
        except KeyspaceError:
            continue
        if kind not in (MotionCommand, Status, ObservationReport, TruthMessage):
            continue
        try:
            msg = decode(payload, kind, key=topic)
        except MessageError:
            continue
        if not isinstance(msg, (MotionCommand, Status, ObservationReport, TruthMessage)):
            continue  # (decode returned the kind asked for)
        key = (int(msg.robot), int(msg.step))
        ids.add(key[0])
        if isinstance(msg, MotionCommand):
            sent[key] = (float(msg.turn_rad), float(msg.drive_m))
            log.first_command_ns[key[1]] = min(msg.stamp_ns, log.first_command_ns.get(key[1], msg.stamp_ns))
        elif isinstance(msg, Status):
            if msg.state == "done":
                done.add(key)
        elif isinstance(msg, ObservationReport):
            log.observations[key] = (np.array(msg.observed, dtype=np.int64), np.array(msg.ranges, dtype=float),
                                     np.array(msg.bearings, dtype=float))
            log.report_ns.setdefault(key, msg.stamp_ns)
        else:
            log.truths[key] = np.array(msg.pose, dtype=float)
    log.commands = {k: v for k, v in sent.items() if k in done}
    log.ids = sorted(ids)
    if not log.observations:
        raise SwarmInputError(f"{path}: the recording holds no ObservationReport (is it a run of swarm coordinator / swarm record?)")
    return log
