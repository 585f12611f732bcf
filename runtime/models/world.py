"""Worlds that simulated robots move in by velocity: the seam between the simulated ROS 2 robots and their physics.

A ``World`` holds the true poses of robots ``ids`` and advances them by ``step(dt, twists)``, the
commanded body twists (n, 2) = (linear m/s, angular rad/s) held over ``dt`` seconds (a differential
drive's wheel speeds map to one twist: v = (r_w + l_w) r / 2, w = (r_w - l_w) r / b). It answers
``poses()`` (true, (n, 3)), ``odometry()`` (what the wheel encoders integrate, (n, 3), drifting from
the truth), ``speeds()`` (the twists the encoders measure now, (n, 2)) and ``sightings(index)`` (one
sensor frame of robot ``index``: observed ids, ranges m, bearings rad in its body frame).
``robot_agent.ros2_robots`` drives any world through these calls only; a world registers its
constructor in ``WORLDS`` under a name of ``swarm ros2 robots --world``: ``kinematic`` (below) and
``physics`` (``runtime.world.velocity.PhysicsWorld``: bodies that push, wheels that slip; docs/physics.md).

``KinematicWorld`` is the project's model (runtime/models/motion.py, sensing.py) integrated in time.
A *segment* is a motion from rest to rest; at its start the robot draws (turn noise, relative drive
noise) from its motion stream, exactly as ``execute_command`` does per command. The linear speed is
scaled by (1 + drive noise) through the segment, and the turn noise is added to the heading once the
turning is over (when the robot starts to drive, or stops): a turn-then-drive command executed as a
velocity profile ends where ``apply_motion`` puts it, with the same distribution. Odometry integrates
the commanded twists without noise (the encoders do not see slip).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

import numpy as np

from runtime.errors import OptionError, SwarmInputError
from runtime.models.config import ModelConfig
from runtime.models.geometry import wrap_angle
from runtime.models.motion import draw_motion_noise
from runtime.models.rng import Stream, robot_rng
from runtime.models.sensing import sense_robot


class World(Protocol):
    """What the simulated robots need of a world (module doc)."""

    ids: np.ndarray

    def step(self, dt: float, twists: np.ndarray) -> None: ...

    def poses(self) -> np.ndarray: ...

    def odometry(self) -> np.ndarray: ...

    def speeds(self) -> np.ndarray: ...

    def sightings(self, index: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]: ...


def integrate_twist(poses: np.ndarray, v: np.ndarray, w: np.ndarray, dt: float) -> np.ndarray:
    """Poses (n, 3) after driving at (v, w) for ``dt`` seconds, exactly (arcs; straight lines where w = 0)."""
    th = poses[:, 2]
    dth = w * dt
    small = np.abs(dth) < 1e-9
    safe_w = np.where(small, 1.0, w)
    arc_x = np.where(small, v * dt * np.cos(th + dth / 2), v / safe_w * (np.sin(th + dth) - np.sin(th)))
    arc_y = np.where(small, v * dt * np.sin(th + dth / 2), -v / safe_w * (np.cos(th + dth) - np.cos(th)))
    return np.stack([poses[:, 0] + arc_x, poses[:, 1] + arc_y, wrap_angle(th + dth)], axis=1)


class KinematicWorld:
    """Robots ``ids`` starting at ``poses`` (n, 3), moving by the run's motion and sensing model (module doc)."""

    def __init__(self, ids: np.ndarray, poses: np.ndarray, cfg: ModelConfig, seed: int) -> None:
        self.ids = np.asarray(ids, dtype=np.int64)
        self._true = np.array(poses, dtype=float).reshape(len(self.ids), 3)
        if not np.all(np.isfinite(self._true)):
            raise SwarmInputError("initial poses of the world must be finite")
        self._odom = self._true.copy()
        self.cfg = cfg
        self._motion = [robot_rng(seed, int(i), Stream.MOTION) for i in self.ids]
        self._sensing = [robot_rng(seed, int(i), Stream.SENSING) for i in self.ids]
        n = len(self.ids)
        self._moving = np.zeros(n, bool)
        self._turn_noise = np.zeros(n)  # of the current segment, until applied
        self._pending = np.zeros(n, bool)  # turn noise not yet applied
        self._drive_scale = np.ones(n)
        self.segments = np.zeros(n, np.int64)  # motions started, per robot
        self._twists = np.zeros((n, 2))  # of the latest step

    def step(self, dt: float, twists: np.ndarray) -> None:
        twists = np.asarray(twists, dtype=float).reshape(len(self.ids), 2)
        v, w = twists[:, 0], twists[:, 1]
        moving = (v != 0.0) | (w != 0.0)
        for k in np.flatnonzero(moving & ~self._moving):  # a segment starts: its noise, as execute_command draws it
            turn, drive = draw_motion_noise(self._motion[k], (), self.cfg)
            self._turn_noise[k], self._drive_scale[k], self._pending[k] = float(turn), 1.0 + float(drive), True
            self.segments[k] += 1
        turned = self._pending & ((v != 0.0) | ~moving)  # the turning is over: driving starts, or the robot stopped
        self._true[turned, 2] = wrap_angle(self._true[turned, 2] + self._turn_noise[turned])
        self._pending &= ~turned
        self._moving = moving
        self._true = integrate_twist(self._true, v * self._drive_scale, w, dt)
        self._odom = integrate_twist(self._odom, v, w, dt)
        self._twists = twists.copy()

    def poses(self) -> np.ndarray:
        return self._true.copy()

    def odometry(self) -> np.ndarray:
        return self._odom.copy()

    def speeds(self) -> np.ndarray:
        """The commanded twists of the latest step: the encoders count them exactly."""
        return self._twists.copy()

    def sightings(self, index: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        nb, rho, phi = sense_robot(self._true, index, self.cfg, self._sensing[index])
        return self.ids[nb], rho, phi


def physics_world(ids: np.ndarray, poses: np.ndarray, cfg: ModelConfig, seed: int) -> World:
    """The physical world (the ``physics`` extra) of the default parameters for ``cfg`` (its body radius, sensing range)."""
    from runtime.world.params import PhysicsParams  # noqa: PLC0415 - the physics extra, only when asked for
    from runtime.world.physics import require_pymunk  # noqa: PLC0415
    from runtime.world.velocity import PhysicsWorld  # noqa: PLC0415

    require_pymunk()
    return PhysicsWorld(ids, poses, PhysicsParams.for_model(cfg), seed)


WorldFactory = Callable[[np.ndarray, np.ndarray, ModelConfig, int], World]
WORLDS: dict[str, WorldFactory] = {"kinematic": KinematicWorld, "physics": physics_world}  # name -> constructor(ids, poses, model, seed)


def make_world(kind: str, ids: np.ndarray, poses: np.ndarray, cfg: ModelConfig, seed: int) -> World:
    """The world ``kind`` (a name of ``WORLDS``) of robots ``ids`` at ``poses``."""
    if kind not in WORLDS:
        raise OptionError("world", f"{kind}: not one of {', '.join(sorted(WORLDS))}")
    return WORLDS[kind](ids, poses, cfg, seed)
