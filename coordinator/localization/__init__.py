"""Swarm localization behind one interface (Section 5): the paper's method and a joint alternative.

A ``Localizer`` turns the pre-step estimate, the step's commands and the post-step
observations into the post-step estimate. The motion strategy only talks to this
interface, which is what lets it "work with any localization method".
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from coordinator.localization.joint import JointLocalizer
from coordinator.localization.paper import PaperLocalizer
from coordinator.localization.topology import Topology
from runtime.models.config import ModelConfig
from runtime.errors import SwarmInputError
from runtime.models.state import Observations, StepCommands, SwarmEstimate


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


LOCALIZERS: dict[str, type[PaperLocalizer] | type[JointLocalizer]] = {"paper": PaperLocalizer, "joint": JointLocalizer}


def make_localizer(name: str, cfg: ModelConfig, huber: float | None = None) -> Localizer:
    """The localizer called ``name`` (``paper`` or ``joint``)."""
    try:
        cls = LOCALIZERS[name]
    except KeyError:
        raise SwarmInputError(f"unknown localizer {name!r}; choose one of {sorted(LOCALIZERS)}") from None
    return cls(cfg, huber=huber)


__all__ = ["Localizer", "JointLocalizer", "PaperLocalizer", "Topology", "make_localizer", "LOCALIZERS"]
