"""Drivers: what an agent moves and senses with, behind one ``Driver`` interface.

``SimDriver`` is a simulated robot: it holds its own true pose, moves with the motion
model (``runtime.models.motion.execute_command``, noise from ``robot_rng(seed, id, MOTION)``)
and senses with the sensing model (``runtime.models.sensing.sense_robot``, noise from
``robot_rng(seed, id, SENSING)``), so an agent process draws exactly the numbers the
in-process ``runtime.models.simulation.SimulatedSwarm`` draws for that robot with that seed.
Sensing needs the neighbours' true poses: the agent hands them to ``sense`` (simulated
agents exchange ``TruthMessage``s, see ``robot_agent.agent``). A hardware driver
implements the same interface (``Driver``, an ABC; docs/drivers.md) and ignores ``peers``.
"""

from __future__ import annotations

import time
from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from runtime.errors import SwarmInputError, SwarmRunError
from runtime.models.config import ModelConfig
from runtime.models.motion import execute_command
from runtime.models.rng import Stream, robot_rng
from runtime.models.sensing import sense_robot
from runtime.wire.messages import MotionCommand

if TYPE_CHECKING:
    import zenoh

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


class DriverRefused(SwarmRunError):
    """The robot did not execute the command; the text is the reason."""


class RobotLost(SwarmRunError):
    """The robot stopped answering; the text says how."""


class DriverFault(RobotLost):
    """The driver failed (raised something else, or did not return in time): the robot is treated as lost."""


@dataclass(frozen=True)
class DriverContext:
    """What ``swarm agent`` knows when it builds a driver (``--driver package.module:Class`` calls ``Class(context)``).

    ``pose``: the robot's initial true pose (x, y, heading; m, rad) when the agent was given one
    (``--pose`` or ``--trajectory``), else None; ``model``: the run's noise model (``--model``
    and the model flags); ``options``: the ``--driver-option KEY=VALUE`` pairs, as strings.
    """

    robot: int
    ids: tuple[int, ...]
    run: str
    seed: int = 0
    pose: np.ndarray | None = None
    model: ModelConfig = ModelConfig()
    options: Mapping[str, str] = field(default_factory=dict)


class Driver(ABC):
    """One robot's actuators and sensors, as the agent uses them (docs/drivers.md).

    ``SimDriver`` (simulated robot) and ``robot_agent.gateway_driver.GatewayDriver`` (a robot behind
    a link process) implement it, and so does a lab's own driver loaded with ``--driver
    package.module:Class``. The agent calls ``execute`` and ``sense`` from its loop thread, one
    at a time; ``estop`` may come from any thread at any time, also while ``execute`` runs.
    ``execute`` and ``sense`` may raise ``DriverRefused`` (not executed, with the reason) or
    ``RobotLost`` (the robot stopped answering); any other exception, or no return within the
    agent's command timeout, is a driver fault: the agent calls ``estop``, reports the robot
    lost and ends. A driver that notices while idle that its robot is gone calls ``report_lost``.
    """

    simulated: bool = False  # True: the agent publishes TruthMessages and passes peers' true poses to sense()
    instantaneous: bool = False  # True: ``execute`` takes no wall time, so the agent answers with ``done`` alone (no ``accepted``)
    on_lost: Callable[[str], None] | None = None  # set by the agent; see report_lost

    def attach(self, session: zenoh.Session) -> None:  # noqa: B027 - optional hook, nothing to do by default
        """The agent's Zenoh session is open (a driver that talks to a link process subscribes here)."""

    def detach(self) -> None:  # noqa: B027
        """The agent is leaving: release what ``attach`` and the constructor took (after ``stop``)."""

    def ready(self, timeout_s: float) -> bool:
        """Whether the robot can be reached now, waiting up to ``timeout_s`` seconds (the agent declares
        its liveliness token, "robot reachable", only once this is True)."""
        return True

    @abstractmethod
    def execute(self, command: MotionCommand) -> np.ndarray | None:
        """Turn ``command.turn_rad`` then drive ``command.drive_m`` (body frame), returning once the motion is over;
        the new true pose (3,) if known, else None."""

    @abstractmethod
    def sense(self, peers: PeerPoses | Mapping[int, np.ndarray] | None, step: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(observed ids, ranges m, bearings rad in the body frame) of the neighbours after ``step``.

        ``peers``: the true poses of every robot still in the run (own included) for simulated drivers, else None.
        """

    @abstractmethod
    def estop(self, step: int = 0) -> None:
        """Emergency stop (any thread): stop now and refuse every later command (``DriverRefused``)."""

    @abstractmethod
    def stop(self) -> None:
        """Halt any motion now, not latched: the agent calls it whenever it ends (signal, robot lost, fault)."""

    def true_pose(self) -> np.ndarray | None:
        """The true pose (3,) (simulation, or a tracker the driver reads), or None."""
        return None

    def report_lost(self, reason: str) -> None:
        """Tell the agent the robot is gone while no call is in progress (any thread); the agent ends, exit 3."""
        if self.on_lost is not None:
            self.on_lost(reason)


class SimDriver(Driver):
    """A simulated robot ``robot`` of the run ``ids``, starting at ``pose``, seeded with ``seed``."""

    simulated = True

    def __init__(self, robot: int, ids: list[int], pose: np.ndarray | Sequence[float], cfg: ModelConfig, seed: int,
                 motion_time_s: float = 0.0) -> None:
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
        self.instantaneous = self.motion_time_s == 0
        self._motion = robot_rng(seed, robot, Stream.MOTION)
        self._sensing = robot_rng(seed, robot, Stream.SENSING)
        self._order_cache: tuple[bytes, np.ndarray, int] | None = None  # ``_run_order``'s last answer
        self.estopped = False

    def attach(self, session: zenoh.Session) -> None:
        """Nothing to connect: the simulated robot lives in this process."""

    def detach(self) -> None:
        """Nothing to disconnect."""

    def ready(self, timeout_s: float) -> bool:
        return True

    def estop(self, step: int = 0) -> None:
        self.estopped = True

    def stop(self) -> None:
        """Nothing to halt: a simulated motion is over when ``execute`` returns."""

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
        peers = PeerPoses(np.empty(0, np.int64), np.empty((0, 3))) if peers is None else PeerPoses.of(peers)
        order, index = self._run_order(peers.ids)  # raises for no peers, as for any set without this robot
        poses = peers.poses[order]
        poses[index] = self._pose
        nb, rho, phi = sense_robot(poses, index, self.cfg, self._sensing)
        return peers.ids[order][nb], rho, phi

    def _run_order(self, ids: np.ndarray) -> tuple[np.ndarray, int]:
        """(permutation putting ``ids`` in the run's order, as the noise streams are drawn (lost robots absent),
        this robot's position in it); the last answer is kept, since the robots present rarely change."""
        key = ids.tobytes()
        if self._order_cache is not None and self._order_cache[0] == key:
            return self._order_cache[1], self._order_cache[2]
        own = np.flatnonzero(ids == self.robot)
        if len(own) != 1 or not np.isin(ids, self._ids).all():
            raise SwarmInputError(f"simulated sensing of robot {self.robot} needs the true poses of the robots present "
                                  f"(its own included, run robots only); got {ids.tolist()}")
        sorter = np.argsort(self._ids)
        rank = sorter[np.searchsorted(self._ids, ids, sorter=sorter)]  # position in the run's order
        order = np.argsort(rank)
        index = int(np.flatnonzero(ids[order] == self.robot)[0])
        self._order_cache = (key, order, index)
        return order, index
