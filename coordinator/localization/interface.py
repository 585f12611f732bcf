"""The ``Localizer`` interface (re-exported by ``coordinator.localization``): what the executor, the anchor selection's
Monte Carlo and the registry know of a localizer."""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol

import numpy as np

from runtime.models.state import Observations, StepCommands, SwarmEstimate

if TYPE_CHECKING:
    from coordinator.localization.topology import Topology


class Localizer(Protocol):
    """Post-step swarm localization."""

    name: str

    def localize(self, prior: SwarmEstimate, step: StepCommands, obs: Observations) -> SwarmEstimate:
        """Post-step poses and covariances of every robot in ``prior.ids`` (global frame)."""
        ...

    def localize_subset(self, prior: SwarmEstimate, step: StepCommands, obs: Observations, keep: np.ndarray) -> SwarmEstimate:
        """``localize`` of the robots where ``keep`` (n,) alone; the others keep their dead reckoning."""
        ...

    def topology(self, ids: np.ndarray, obs: Observations, initial_poses: np.ndarray | None = None) -> Topology:
        """Relative poses from observations alone, in the reference robot's frame."""
        ...
