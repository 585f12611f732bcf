"""The physical world behind the velocity seam of the simulated ROS 2 robots (``swarm ros2 robots --world physics``).

``PhysicsWorld`` is a ``runtime.models.world.World`` over ``runtime.world.physics.World``: ``step(dt, twists)``
sets each robot's body twist (its ``cmd_vel``; the wheels follow within their speed and acceleration
limits, a motion from rest draws its wheel-speed factors, the ground's traction lets them slip) and
advances the world by ``dt`` in its fixed steps (the remainder carried to the next call); ``poses`` are
the bodies', ``odometry`` and ``speeds`` the wheel encoders' (blind to the wheels' factors, slip and
pushes), ``sightings`` the world's sensor (range and bearing noise, occlusion, field of view).
``take_quiet`` says when the world came to rest after a motion, with the contacts and stalls meanwhile.
"""

from __future__ import annotations

import numpy as np

from runtime.world.params import PhysicsParams
from runtime.world.physics import World, WorldEvent


class PhysicsWorld:
    """Robots ``ids`` at ``poses`` (n, 3) in a physical world of ``params``, seeded with ``seed`` (module doc)."""

    def __init__(self, ids: np.ndarray, poses: np.ndarray, params: PhysicsParams, seed: int) -> None:
        self.ids = np.asarray(ids, dtype=np.int64)
        self.world = World(self.ids.tolist(), poses, params, seed, encoders=True)
        self._robots = [int(i) for i in self.ids]
        self._twists = np.zeros((len(self.ids), 2))  # as last set
        self._carry = 0.0  # world time owed to the next step (s)
        self._moved = False  # something moved since the last quiet moment

    def step(self, dt: float, twists: np.ndarray) -> None:
        twists = np.asarray(twists, dtype=float).reshape(len(self.ids), 2)
        for k in np.flatnonzero(np.any(twists != self._twists, axis=1)):
            self.world.set_twist(self._robots[k], float(twists[k, 0]), float(twists[k, 1]))
        self._twists = twists.copy()
        dt_s = self.world.params.dt_s
        self._carry += max(float(dt), 0.0)
        n = int(self._carry / dt_s + 1e-9)
        self._carry -= n * dt_s
        if n:
            self.world.step(n)
        self._moved |= bool(twists.any()) or self.world.busy()

    def poses(self) -> np.ndarray:
        return self.world.poses()

    def odometry(self) -> np.ndarray:
        return self.world.odometry()

    def speeds(self) -> np.ndarray:
        """What the encoders measured in the last step: (v m/s, w rad/s) per robot (n, 2)."""
        return self.world.encoder_twists()

    def sightings(self, index: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return self.world.sense(self._robots[index])

    def take_quiet(self) -> tuple[float, list[WorldEvent], np.ndarray] | None:
        """(world time, contacts and stalls since the last quiet moment, true poses) once the world is at rest after a
        motion (no wheel turns, no body moves); None while something moves, or when nothing moved since."""
        if not self._moved or self.world.busy() or not self.world.at_rest():
            return None
        self._moved = False
        return self.world.time_s, self.world.take_events(), self.world.poses()

    def close(self) -> None:
        self.world.close()
