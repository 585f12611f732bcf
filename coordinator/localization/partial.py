"""Localize what can be localized: the runtime's answer to a robot out of sight.

When some robots are unobserved or cut off from the rest after a step, the largest
observable group (``graph.observable_subset``) is localized as usual and the others
keep their dead-reckoning estimate (Phase 1.1), instead of the whole swarm falling back
to dead reckoning. The robots left out, and why, are returned so the caller can report them.
"""

from __future__ import annotations

from coordinator.localization.dead_reckoning import dead_reckon
from coordinator.localization.graph import observable_subset
from runtime.config import ModelConfig
from runtime.errors import LocalizationError
from runtime.state import Observations, StepCommands, SwarmEstimate


def localize_observable(
    localizer, prior: SwarmEstimate, step: StepCommands, obs: Observations, cfg: ModelConfig
) -> tuple[SwarmEstimate, dict[int, str]]:
    """Post-step estimate and {robot id: reason} of the robots that kept dead reckoning."""
    try:
        return localizer.localize(prior, step, obs), {}
    except LocalizationError as exc:
        failure = exc
    dr = dead_reckon(prior, step, cfg)
    i, j = obs.indexed(prior.ids)
    keep, excluded = observable_subset(prior.ids, i, j)
    if keep.sum() < 2 or not excluded:
        return dr, {int(r): failure.reason for r in prior.ids}
    try:
        sub = localizer.localize(prior.select(keep), step.select(keep), obs.select(keep[i] & keep[j]))
    except LocalizationError as exc:
        return dr, {int(r): exc.reason for r in prior.ids}
    poses, cov = dr.poses.copy(), dr.cov.copy()
    poses[keep], cov[keep] = sub.poses, sub.cov
    return SwarmEstimate(prior.ids, poses, cov), excluded


__all__ = ["localize_observable"]
