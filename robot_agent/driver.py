"""Drivers: what an agent moves and senses with, behind one ``Driver`` interface.

``SimDriver`` is a simulated robot: it holds its own true pose, moves with the motion
model (``runtime.models.motion.execute_command``, noise from ``robot_rng(seed, id, MOTION)``)
and senses with the sensing model (``runtime.models.sensing.sense_robot``, noise from
``robot_rng(seed, id, SENSING)``), so an agent process draws exactly the numbers the
in-process ``runtime.models.simulation.SimulatedSwarm`` draws for that robot with that seed.
Sensing needs the neighbours' true poses: the agent hands them to ``sense`` (simulated
agents exchange ``TruthMessage``s, see ``robot_agent.agent``). A hardware driver
implements the same interface and ignores ``peers``.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from runtime.models.config import ModelConfig
from runtime.errors import SwarmInputError
from runtime.wire.messages import MotionCommand
from runtime.models.motion import execute_command
from runtime.models.rng import Stream, robot_rng
from runtime.models.sensing import sense_robot


@dataclass(frozen=True)
class PeerPoses:
    """The true poses (n, 3) of robots ``ids`` (n,) of one step (simulation): what a simulated robot senses.

    Built once per process from a ``TruthSetMessage`` and shared read-only by the agents it hosts,
    so each agent's sensing is array work, not a rebuild of n poses.
    """

    ids: np.ndarray
    poses: np.ndarray

    @classmethod
    def of(cls, peers: PeerPoses | Mapping[int, np.ndarray]) -> PeerPoses:
        """``peers`` as ``PeerPoses`` (a mapping robot id -> pose is converted)."""
        if isinstance(peers, PeerPoses):
            return peers
        ids = np.array(sorted(peers), dtype=np.int64)
        return cls(ids, np.array([peers[int(i)] for i in ids], dtype=float).reshape(len(ids), 3))


class DriverRefused(Exception):
    """The robot did not execute the command; the text is the reason."""


class RobotLost(Exception):
    """The robot stopped answering; the text says how."""


class Driver(Protocol):
    """One robot's actuators and sensors (``SimDriver`` here, ``GatewayDriver`` for robots behind a link).

    ``execute`` and ``sense`` may raise ``DriverRefused`` (not executed, with the reason) or
    ``RobotLost`` (the robot stopped answering); ``estop`` may be called from any thread.
    """

    simulated: bool  # True: the agent publishes TruthMessages and passes peers' true poses to sense()

    def attach(self, session) -> None:
        """The agent's Zenoh session is open (a driver that talks to a link process subscribes here)."""
        ...

    def detach(self) -> None:
        """The session is about to close."""
        ...

    def ready(self, timeout_s: float) -> bool:
        """Whether the robot can be reached now, waiting up to ``timeout_s`` seconds."""
        ...

    def estop(self, step: int = 0) -> None:
        """Emergency stop: stop now and refuse every later command."""
        ...

    def execute(self, command: MotionCommand) -> np.ndarray | None:
        """Turn ``command.turn_rad`` then drive ``command.drive_m`` (body frame); the new true pose (3,) if known, else None."""
        ...

    def true_pose(self) -> np.ndarray | None:
        """The true pose (3,) (simulation), or None (hardware)."""
        ...

    def sense(self, peers: PeerPoses | Mapping[int, np.ndarray] | None, step: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(observed ids, ranges m, bearings rad in the body frame) of the neighbours after ``step``.

        ``peers``: the true poses of every robot still in the run (own included), for simulated drivers.
        """
        ...


class SimDriver:
    """A simulated robot ``robot`` of the run ``ids``, starting at ``pose``, seeded with ``seed``."""

    simulated = True

    def __init__(self, robot: int, ids: list[int], pose: np.ndarray, cfg: ModelConfig, seed: int, motion_time_s: float = 0.0) -> None:
        if robot not in ids:
            raise SwarmInputError(f"robot {robot} is not one of the run's robots {ids}")
        self.robot = int(robot)
        self.ids = [int(i) for i in ids]
        self._ids = np.array(self.ids, dtype=np.int64)
        self._pose = np.array(pose, dtype=float).reshape(3)
        if not np.all(np.isfinite(self._pose)):
            raise SwarmInputError(f"initial pose of robot {robot} must be finite, got {self._pose.tolist()}")
        self.cfg = cfg
        self.motion_time_s = float(motion_time_s)  # wall time a motion takes (to make runs observable)
        self._motion = robot_rng(seed, robot, Stream.MOTION)
        self._sensing = robot_rng(seed, robot, Stream.SENSING)
        self.estopped = False

    def attach(self, session) -> None:
        """Nothing to connect: the simulated robot lives in this process."""

    def detach(self) -> None:
        """Nothing to disconnect."""

    def ready(self, timeout_s: float) -> bool:
        return True

    def estop(self, step: int = 0) -> None:
        self.estopped = True

    def execute(self, command: MotionCommand) -> np.ndarray:
        if self.estopped:
            raise DriverRefused("emergency stop")
        self._pose = execute_command(self._pose, np.array([command.turn_rad, command.drive_m], dtype=float), self.cfg, self._motion)
        if self.motion_time_s > 0:
            time.sleep(self.motion_time_s)
        return self._pose.copy()

    def true_pose(self) -> np.ndarray:
        return self._pose.copy()

    def sense(self, peers: PeerPoses | Mapping[int, np.ndarray] | None, step: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        peers = None if peers is None else PeerPoses.of(peers)
        own = None if peers is None else np.flatnonzero(peers.ids == self.robot)
        if peers is None or len(own) != 1 or not np.isin(peers.ids, self._ids).all():
            got = [] if peers is None else peers.ids.tolist()
            raise SwarmInputError(f"simulated sensing of robot {self.robot} needs the true poses of the robots present "
                                  f"(its own included, run robots only); got {got}")
        sorter = np.argsort(self._ids)
        rank = sorter[np.searchsorted(self._ids, peers.ids, sorter=sorter)]  # position in the run's order
        order = np.argsort(rank)  # the run's order, as the noise streams are drawn; lost robots are absent
        present = peers.ids[order]
        poses = peers.poses[order]
        index = int(np.flatnonzero(present == self.robot)[0])
        poses[index] = self._pose
        nb, rho, phi = sense_robot(poses, index, self.cfg, self._sensing)
        return present[nb], rho, phi
