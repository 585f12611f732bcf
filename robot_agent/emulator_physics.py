"""Emulated robots in the physical world (``swarm emulate-robots --physics``, docs/physics.md, docs/emulator.md).

``PhysicalEmulatedWorld`` is an ``EmulatedWorld`` whose robots are bodies of one ``SharedWorld``
(``robot_agent.physics_driver``): an accepted COMMAND starts the robot's wheel-speed profiles at
once (``begin``) and its DONE goes out when the world is still again, so the robots of a step
move together, collide and push; OBSERVATION comes from the world's sensor (occlusion, field of
view). A ``--miscalibrate`` robot still drives ``drive * motion_scale`` and measures with its
range bias and bearing offset. With a Zenoh session the world's contacts, stalls and true poses
go out as ``PhysicsEvent``s (``SharedWorld.attach``).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping

import numpy as np

from robot_agent.emulator import EmulatedWorld
from robot_agent.physics_driver import SharedWorld
from runtime.gateway.config import Calibration
from runtime.models.config import ModelConfig
from runtime.world.params import PhysicsParams
from runtime.world.physics import World


class PhysicalEmulatedWorld(EmulatedWorld):
    """``EmulatedWorld`` of the robots ``traj_ids`` in a physical world of ``params`` (``speed``: world s per wall s, 0 = as
    fast as it computes); ``run`` names the run its ``PhysicsEvent``s belong to."""

    physical = True

    def __init__(self, traj_ids: Iterable[int], initial_poses: np.ndarray, cfg: ModelConfig, seed: int, params: PhysicsParams,
                 speed: float = 0.0, run: str = "emulated", calibration: Mapping[int, Calibration] | None = None,
                 heartbeat_timeout_s: float = 1.0) -> None:
        super().__init__(traj_ids, initial_poses, cfg, seed, calibration, 0.0, heartbeat_timeout_s)
        self.shared = SharedWorld(World(self.ids, self._poses, params, seed), run, speed)

    def close(self) -> None:
        self.shared.realtime.close()

    def begin(self, robot: int, turn_rad: float, drive_m: float, step: int, done: Callable[[], None]) -> None:
        """Start ``robot``'s command (its true ``motion_scale`` applied); ``done()`` once the world is still."""
        self.index(robot)
        driven = self.calibration.get(robot, Calibration()).driven(drive_m)
        self.shared.realtime.begin(robot, turn_rad, driven, step, lambda pose: done())

    def halt(self, robot: int) -> None:
        self.shared.realtime.halt(robot)

    def move(self, robot: int, turn_rad: float, drive_m: float) -> np.ndarray:
        """The motion already happened in the world (``begin``): the robot's true pose now."""
        return self.pose(robot)

    def pose(self, robot: int) -> np.ndarray:
        self.index(robot)
        return self.shared.realtime.pose(robot)

    def poses(self) -> np.ndarray:
        return self.shared.realtime.poses()

    def truth(self, robot: int) -> tuple[int, np.ndarray]:
        self.index(robot)
        with self._lock:
            step = self._truth_step[robot]
        return step, self.shared.realtime.pose(robot)

    def sense(self, robot: int, step: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The world's sightings of ``robot`` (with its calibration's biases); with ``step``, the truth listeners first."""
        self.index(robot)
        cal = self.calibration.get(robot, Calibration())
        with self._lock:
            if step is not None:
                self._truth_step[robot] = int(step)
            listeners = list(self._listeners) if step is not None else []
        pose = self.shared.realtime.pose(robot)
        ids, rho, phi = self.shared.realtime.sense(robot)
        for listener in listeners:
            listener(robot, int(step), pose)  # type: ignore[arg-type]  # step is not None when there are listeners
        return ids, cal.measured_ranges(rho), cal.measured_bearings(phi)
