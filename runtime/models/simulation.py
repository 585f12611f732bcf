"""In-process simulated swarm: the ground truth world behind the swarm-backend interface.

Each robot draws its motion and sensing noise from its own seeded streams
(``runtime.models.rng``), exactly as a simulated agent process does, so an in-process run and a
distributed run with the same seed produce the same numbers.
"""

from __future__ import annotations

import numpy as np

from runtime.errors import SwarmInputError
from runtime.models.config import ModelConfig
from runtime.models.motion import execute_command
from runtime.models.rng import Stream, robot_rngs
from runtime.models.sensing import sense_swarm
from runtime.models.state import Observations, StepCommands


class SimulatedSwarm:
    """True poses of ``ids`` (SI units), moved by commands and sensed with noise."""

    def __init__(self, ids: np.ndarray, true_poses: np.ndarray, cfg: ModelConfig, seed: int) -> None:
        self.ids = np.asarray(ids, dtype=np.int64)
        self._poses = np.array(true_poses, dtype=float)
        self.cfg = cfg
        self._motion = robot_rngs(seed, self.ids, Stream.MOTION)
        self._sensing = robot_rngs(seed, self.ids, Stream.SENSING)

    def execute(self, step: StepCommands) -> None:
        """Mobile robots execute their body-frame commands; anchors stay still."""
        if not np.array_equal(step.ids, self.ids):
            raise SwarmInputError(f"commands for robots {step.ids.tolist()}, swarm has {self.ids.tolist()}")
        for k in np.flatnonzero(step.moving):
            self._poses[k] = execute_command(self._poses[k], step.commands[k], self.cfg, self._motion[k])

    def observe(self) -> Observations:
        """Every robot's range/bearing observations of its neighbours."""
        return sense_swarm(self._poses, self.ids, self.cfg, self._sensing)

    def true_poses(self) -> np.ndarray:
        """Ground truth (n, 3), for evaluation only."""
        return self._poses.copy()

    def take_lost(self) -> dict[int, str]:
        """The in-process swarm never loses a robot."""
        return {}
