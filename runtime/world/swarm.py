"""The physical world behind the swarm-backend interface: an in-process run whose robots the noise model did not move.

``PhysicsSwarm`` has the interface of ``runtime.models.simulation.SimulatedSwarm``: each step, every
mover starts its command at the same world time and the world runs until every command is over
and every body is at rest; sensing comes from the world. Deterministic for a seed. ``events``
holds what happened, (global step, ``Contact`` | ``Stuck``), for evaluation.
"""

from __future__ import annotations

import numpy as np

from runtime.errors import SwarmInputError
from runtime.models.state import Observations, StepCommands
from runtime.world.params import PhysicsParams
from runtime.world.physics import World, WorldEvent

SETTLE_S = 600.0  # world seconds a step may take at most (a 1 m drive at the default speed takes ~20 s)


class PhysicsSwarm:
    """Robots ``ids`` at ``true_poses`` in a ``World`` of ``params``, seeded with ``seed`` (SI units)."""

    def __init__(self, ids: np.ndarray, true_poses: np.ndarray, params: PhysicsParams, seed: int) -> None:
        self.ids = np.asarray(ids, dtype=np.int64)
        self.world = World(self.ids.tolist(), true_poses, params, seed)
        self.step = 0
        self.events: list[tuple[int, WorldEvent]] = []

    def execute(self, step: StepCommands) -> None:
        """The mobile robots' commands start together; returns once the world is still again."""
        if not np.array_equal(step.ids, self.ids):
            raise SwarmInputError(f"commands for robots {step.ids.tolist()}, swarm has {self.ids.tolist()}")
        self.step += 1
        for k in np.flatnonzero(step.moving):
            self.world.command(int(self.ids[k]), float(step.commands[k, 0]), float(step.commands[k, 1]))
        self.world.settle(SETTLE_S)
        self.events += [(self.step, e) for e in self.world.take_events()]

    def observe(self) -> Observations:
        """Every robot's sightings of its neighbours, from the world."""
        observer, observed, ranges, bearings = [], [], [], []
        for robot in self.ids:
            seen, rho, phi = self.world.sense(int(robot))
            observer.append(np.full(len(seen), robot))
            observed.append(seen)
            ranges.append(rho)
            bearings.append(phi)
        return Observations(np.concatenate(observer), np.concatenate(observed), np.concatenate(ranges), np.concatenate(bearings))

    def true_poses(self) -> np.ndarray:
        """Ground truth (n, 3), for evaluation only."""
        return self.world.poses()

    def take_lost(self) -> dict[int, str]:
        """The in-process world never loses a robot."""
        return {}

    def close(self) -> None:
        self.world.close()
