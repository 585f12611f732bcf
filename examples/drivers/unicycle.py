"""A complete minimal driver (docs/drivers.md): one robot the agent drives from Python.

    swarm launch -n 4 --driver examples/drivers/unicycle.py:UnicycleDriver --driver-option speed=0.5
    swarm agent --id 0 --ids 0,1 --run lab --hub tcp/127.0.0.1:7447 --pose 0,0,0 \\
        --driver examples/drivers/unicycle.py:UnicycleDriver

``Unicycle`` below stands in for a lab's robot API: motors (``turn_by``, ``forward_by``,
``halt``) and a range-bearing sensor (``detections``), here a few lines of kinematics with
the run's noise model so the example runs without hardware. ``UnicycleDriver`` is what a
lab writes: keep its structure and replace ``Unicycle`` by the robot's own Python API; a
robot with its own sensor sets ``simulated = False`` and reads ``detections`` from it
(the agent then passes ``peers=None``).

Options (``--driver-option KEY=VALUE``): ``speed`` (m/s, default 0: a motion takes no time)
and ``turn_rate`` (rad/s, default 0: a turn takes no time).
"""

from __future__ import annotations

import threading
import time

import numpy as np

from robot_agent.driver import Driver, DriverContext, DriverRefused, PeerPoses

SLICE_S = 0.02  # a motion is executed in slices this long, so stop() and estop() end it within a slice


class Unicycle:
    """The stand-in robot: a pose, noisy motors and a noisy range-bearing sensor (SI units)."""

    def __init__(self, ctx: DriverContext, speed: float, turn_rate: float) -> None:
        self.pose = np.zeros(3) if ctx.pose is None else np.array(ctx.pose, dtype=float)
        self.model, self.speed, self.turn_rate = ctx.model, speed, turn_rate
        self.rng = np.random.default_rng([ctx.seed, ctx.robot])

    def _run(self, seconds: float, halt: threading.Event) -> float:
        """Spend ``seconds`` in slices; the share of the motion done before ``halt`` was set."""
        start = time.monotonic()
        while time.monotonic() - start < seconds:
            if halt.wait(SLICE_S):
                return min(1.0, (time.monotonic() - start) / seconds)
        return 1.0

    def turn_by(self, angle: float, halt: threading.Event) -> None:
        angle += self.rng.normal(0.0, self.model.turn_sigma_rad)
        done = self._run(abs(angle) / self.turn_rate if self.turn_rate > 0 else 0.0, halt)
        self.pose[2] = (self.pose[2] + done * angle + np.pi) % (2 * np.pi) - np.pi

    def forward_by(self, distance: float, halt: threading.Event) -> None:
        distance *= 1.0 + self.rng.normal(0.0, self.model.drive_sigma_frac)
        done = self._run(abs(distance) / self.speed if self.speed > 0 else 0.0, halt)
        self.pose[:2] += done * distance * np.array([np.cos(self.pose[2]), np.sin(self.pose[2])])

    def detections(self, others: PeerPoses) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(ids, ranges, bearings) of the robots within the sensing range, each kept with 1 - dropout."""
        d = others.poses[:, :2] - self.pose[:2]
        ranges = np.hypot(d[:, 0], d[:, 1])
        seen = (ranges > 0) & (ranges <= self.model.sensing_range_m) & (self.rng.random(len(ranges)) >= self.model.dropout_prob)
        bearings = np.arctan2(d[seen, 1], d[seen, 0]) - self.pose[2] + self.rng.normal(0.0, self.model.bearing_sigma_rad, seen.sum())
        noisy = np.maximum(ranges[seen] + self.rng.normal(0.0, self.model.range_sigma_m, seen.sum()), 0.0)
        return others.ids[seen], noisy, (bearings + np.pi) % (2 * np.pi) - np.pi


class UnicycleDriver(Driver):
    """The driver of one ``Unicycle``: what ``swarm agent --driver examples/drivers/unicycle.py:UnicycleDriver`` builds."""

    simulated = True  # the stand-in senses from the true poses the agent passes; a robot with a real sensor: False

    def __init__(self, ctx: DriverContext) -> None:
        self.robot_id = ctx.robot
        self.robot = Unicycle(ctx, float(ctx.options.get("speed", 0.0)), float(ctx.options.get("turn_rate", 0.0)))
        self._halt = threading.Event()  # set by stop() and estop(): the motion in progress ends
        self._estopped = threading.Event()  # latched by estop()

    def execute(self, command) -> np.ndarray:
        if self._estopped.is_set():
            raise DriverRefused("emergency stop")
        if command.turn_rad == 0.0 and command.drive_m == 0.0:
            return self.robot.pose.copy()  # a robot told to stay does not move
        self._halt.clear()
        self.robot.turn_by(command.turn_rad, self._halt)
        self.robot.forward_by(command.drive_m, self._halt)
        if self._halt.is_set():
            raise DriverRefused("emergency stop during the motion" if self._estopped.is_set() else "stopped during the motion")
        return self.robot.pose.copy()

    def sense(self, peers, step: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        others = PeerPoses.of(peers)
        mine = others.ids != self.robot_id
        return self.robot.detections(PeerPoses(others.ids[mine], others.poses[mine]))

    def estop(self, step: int = 0) -> None:
        self._estopped.set()
        self._halt.set()

    def stop(self) -> None:
        self._halt.set()

    def true_pose(self) -> np.ndarray:
        return self.robot.pose.copy()
