"""Localize what can be localized: the runtime's answer to a robot out of sight or a failed solve.

When some robots are unobserved or cut off from the rest after a step, the largest
observable group (``graph.observable_subset``) is localized as usual and the others
keep their dead-reckoning estimate (Phase 1.1), instead of the whole swarm falling back
to dead reckoning. When the solver itself fails (``no-convergence``, ``degenerate``),
the robots its error names are set aside the same way and the rest is localized again
(at most ``MAX_RETRIES`` times). The robots left out, and why, are returned so the
caller can report them.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, TypeVar

import numpy as np

from coordinator.localization.dead_reckoning import dead_reckon, exact_moments
from coordinator.localization.graph import observable_subset
from runtime.errors import LocalizationError
from runtime.models.config import ModelConfig
from runtime.models.state import Observations, StepCommands, SwarmEstimate

if TYPE_CHECKING:
    from coordinator.localization import Localizer

T = TypeVar("T")  # what a solve returns
Subset = Callable[[np.ndarray, np.ndarray, np.ndarray], tuple[np.ndarray, dict[int, str]]]  # (ids, observer, observed) -> (keep, why)

MAX_RETRIES = 3  # solver failures tolerated, each setting aside the robots it names
SOLVER_FAILURES = ("no-convergence", "degenerate")


def solvable_subset(
    solve: Callable[[np.ndarray], T], ids: np.ndarray, obs: Observations, *, retry: bool = True, subset: Subset = observable_subset
) -> tuple[np.ndarray, T, dict[int, str]]:
    """(mask over ``ids`` of the robots solved, ``solve(mask)``'s result, {left-out id: reason}).

    ``solve(mask)`` localizes the robots where ``mask`` is True (observations restricted to them).
    Robots outside the largest observable group (``subset``: a run's rule, ``graph.observable_subset``,
    or measured data's, ``graph.localizable_subset``) are left out first; then, while ``retry`` and
    ``solve`` fails with a solver failure naming some (not all) robots, those are left out too.
    The last ``LocalizationError`` propagates when nothing is left to solve; when fewer than two
    robots are left, it names those left out.
    """
    i, j = obs.indexed(ids)
    keep = np.ones(len(ids), bool)
    excluded: dict[int, str] = {}
    for attempt in range(MAX_RETRIES + 1):
        live = keep[i] & keep[j]
        sub_keep, sub_excluded = subset(ids[keep], *_reindex(keep, i[live], j[live]))
        excluded.update(sub_excluded)
        keep[np.flatnonzero(keep)[~sub_keep]] = False
        if keep.sum() < 2:
            raise LocalizationError("unobserved", ids[~keep] if (~keep).any() else ids, "fewer than two robots can be localized")
        try:
            return keep, solve(keep), excluded
        except LocalizationError as exc:
            named = np.isin(ids, exc.robots) & keep
            left = keep & ~named
            if not retry or attempt == MAX_RETRIES or exc.reason not in SOLVER_FAILURES or not named.any() or left.sum() < 2:
                raise
            for r in ids[named]:
                excluded[int(r)] = exc.reason
            keep &= ~named
    raise AssertionError("unreachable")


def _reindex(keep: np.ndarray, i: np.ndarray, j: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Indices into ``ids`` mapped to indices into ``ids[keep]``."""
    new = np.cumsum(keep) - 1
    return new[i], new[j]


def localize_observable(
    localizer: Localizer, prior: SwarmEstimate, step: StepCommands, obs: Observations, cfg: ModelConfig
) -> tuple[SwarmEstimate, dict[int, str]]:
    """Post-step estimate and {robot id: reason} of the robots that kept dead reckoning.

    ``localizer.localize_subset`` localizes the robots kept and leaves the others at dead
    reckoning (the joint localizer also carries their cross-covariances, ``gauge.merge_subset``).
    """

    def solve(keep: np.ndarray) -> SwarmEstimate:
        return localizer.localize_subset(prior, step, obs, keep)

    try:
        _keep, estimate, excluded = solvable_subset(solve, prior.ids, obs)
    except LocalizationError as exc:
        return dead_reckon(prior, step, cfg, exact_moments(localizer)), {int(r): exc.reason for r in prior.ids}
    return estimate, excluded


__all__ = ["localize_observable", "solvable_subset"]
