"""Motion strategies behind the same executor: the paper's online selection and the baselines.

Method names are those used in every output: ``inchworm`` (online n_a and anchors,
Section 4), ``inchworm-equal-speed`` (the same search with n_a fixed to n_r / 2),
``heuristic-fixed`` (n_a = n_r / 2, heuristic anchors, no search), ``ref57`` (two fixed
random halves alternating, ref. [57]), ``no-anchors`` (everybody moves at once) and
``one-at-a-time`` (n_a = n_r - 1, in id order, as ref. [56]).
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING, Protocol

import numpy as np

from coordinator.plan import Plan, feasible_anchor_counts
from coordinator.selection.heuristic import heuristic_plan
from runtime.errors import SwarmInputError
from runtime.models.config import ModelConfig
from runtime.models.state import SwarmEstimate

if TYPE_CHECKING:  # the search (scipy) is imported when a strategy is made: METHODS stays cheap for parsers
    from coordinator.localization import Localizer
    from coordinator.selection.selector import AnchorSelector, Selection, SelectionConfig

METHODS = ("inchworm", "inchworm-equal-speed", "heuristic-fixed", "ref57", "no-anchors", "one-at-a-time")
HALF_ANCHORED = ("inchworm-equal-speed", "heuristic-fixed", "ref57")  # n_a = n_r / 2: an even swarm only


class Strategy(Protocol):
    name: str

    def plan(self, estimate: SwarmEstimate, desired: np.ndarray) -> tuple[Plan, Selection | None]:
        """The plan for moving from ``estimate`` to ``desired`` (n, 2), and the selection details if any."""
        ...

    def restrict(self, keep: np.ndarray) -> Strategy:
        """The same method for the robots where ``keep`` (n,) is True (the others were lost)."""
        ...


def anchors_for_half(n: int) -> int:
    """The anchor count of a half-anchored method for ``n`` robots: n / 2 (two steps) when n is even,
    else the smallest feasible count above n / 2 (Eq. 7; e.g. 6 of 9 robots, three steps)."""
    return min(k for k in feasible_anchor_counts(n) if 2 * k >= n)


class SelectedStrategy:
    """Anchors chosen online by Monte Carlo search (``inchworm``, ``inchworm-equal-speed``).

    With ``fallback_anchors`` set, a configuration change for which no plan of the
    allowed anchor counts keeps the swarm connected uses the heuristic plan with that
    many anchors instead of stopping the run (``inchworm-equal-speed`` must keep its speed).
    """

    def __init__(self, name: str, selector: AnchorSelector, fallback_anchors: int | None = None) -> None:
        self.name = name
        self.selector = selector
        self.fallback_anchors = fallback_anchors

    def plan(self, estimate: SwarmEstimate, desired: np.ndarray) -> tuple[Plan, Selection | None]:
        from coordinator.selection.selector import NoFeasiblePlanError  # noqa: PLC0415 - loaded by make_strategy already

        try:
            selection = self.selector.select(estimate, desired)
        except NoFeasiblePlanError:
            if self.fallback_anchors is None:
                raise
            return heuristic_plan(estimate.positions, desired, self.fallback_anchors), None
        return selection.plan, selection

    def restrict(self, keep: np.ndarray) -> SelectedStrategy:
        if self.fallback_anchors is None:  # every feasible count of whatever swarm it is given
            return self
        n_a = anchors_for_half(int(np.sum(keep)))
        selector = type(self.selector)(self.selector.cfg, self.selector.localizer,
                                  replace(self.selector.selection, anchor_counts=(n_a,)), self.selector.seed)
        selector.calls = self.selector.calls  # the search's random stream goes on where it was
        return SelectedStrategy(self.name, selector, fallback_anchors=n_a)


class FixedPlanStrategy:
    """The same plan at every configuration change (``ref57``, ``no-anchors``, ``one-at-a-time``)."""

    def __init__(self, name: str, plan: Plan) -> None:
        self.name = name
        self.fixed = plan

    def plan(self, estimate: SwarmEstimate, desired: np.ndarray) -> tuple[Plan, Selection | None]:
        return self.fixed, None

    def restrict(self, keep: np.ndarray) -> FixedPlanStrategy:
        """The fixed groups without the lost robots (``ref57``'s halves may become unequal); empty groups dropped."""
        new_index = np.cumsum(keep) - 1
        groups = [new_index[g[keep[g]]] for g in self.fixed.groups]
        groups = [g for g in groups if len(g)]
        return FixedPlanStrategy(self.name, Plan(np.concatenate(groups), tuple(len(g) for g in groups)))


class HeuristicStrategy:
    """Heuristic anchors (Eq. 11-13) with a fixed anchor count, no search (``heuristic-fixed``)."""

    name = "heuristic-fixed"

    def __init__(self, n_anchors: int) -> None:
        self.n_anchors = n_anchors

    def plan(self, estimate: SwarmEstimate, desired: np.ndarray) -> tuple[Plan, Selection | None]:
        return heuristic_plan(estimate.positions, desired, self.n_anchors), None

    def restrict(self, keep: np.ndarray) -> HeuristicStrategy:
        return HeuristicStrategy(anchors_for_half(int(np.sum(keep))))


def half(n: int, method: str) -> int:
    if n % 2:
        raise SwarmInputError(f"{method} uses n_a = n_r / 2 and needs an even number of robots, got {n}")
    return n // 2


def make_strategy(
    method: str, n: int, cfg: ModelConfig, localizer: Localizer, selection: SelectionConfig, seed: int
) -> Strategy:
    """The strategy called ``method`` for ``n`` robots; ``seed`` fixes its own random choices. ``localizer`` is the
    executor's: the online selection's Monte Carlo simulates it."""
    from coordinator.selection.selector import AnchorSelector  # noqa: PLC0415 - scipy, only when a strategy is made

    if method == "inchworm":
        return SelectedStrategy(method, AnchorSelector(cfg, localizer, selection, seed))
    if method == "inchworm-equal-speed":
        fixed = replace(selection, anchor_counts=(half(n, method),))
        return SelectedStrategy(method, AnchorSelector(cfg, localizer, fixed, seed), fallback_anchors=half(n, method))
    if method == "heuristic-fixed":
        return HeuristicStrategy(half(n, method))
    if method == "ref57":
        halves = np.random.default_rng([seed, 57]).permutation(n)
        return FixedPlanStrategy(method, Plan.equal(halves, half(n, method)))
    if method == "no-anchors":
        return FixedPlanStrategy(method, Plan.equal(np.arange(n), 0))
    if method == "one-at-a-time":
        return FixedPlanStrategy(method, Plan.equal(np.arange(n), n - 1))
    raise SwarmInputError(f"unknown method {method!r}; choose from {', '.join(METHODS)}")
