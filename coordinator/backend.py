"""The swarm-backend interface: all the executor knows about the robots.

Two backends implement it: the in-process simulator (``runtime.models.simulation.SimulatedSwarm``)
and the distributed one over Zenoh (``coordinator.node.zenoh_backend``); the executor is the same for both.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from runtime.models.state import Observations, StepCommands


class BackendEnded(Exception):
    """The backend ended the run for a reason of its own (another coordinator holds the run, a run-wide stop was
    heard): not a fault of the robots, so the executor passes it on as it is."""


class SwarmBackend(Protocol):
    ids: np.ndarray

    def execute(self, step: StepCommands) -> None:
        """Have the mobile robots execute their commands; returns when all are done."""
        ...

    def observe(self) -> Observations:
        """Collect every robot's observations of its neighbours."""
        ...

    def true_poses(self) -> np.ndarray | None:
        """Ground truth (n, 3) for evaluation, or None where there is none (hardware)."""
        ...

    def take_lost(self) -> dict[int, str]:
        """Robots lost since the last call, with why; the backend has stopped them, no longer commands or
        observes them, and drops them from ``ids`` (a backend that never loses robots returns {})."""
        ...
