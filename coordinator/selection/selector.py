"""Outer loop of the anchor selection (Section 4.2.1, Fig. 6): the number of anchors.

For every feasible anchor count n_a (Eq. 7) the inner loop finds the anchors R_a*(n_a)
with the least expected localization error e_l (Eq. 9), seeded by the heuristic
(Eq. 11-13). Then P_v = 1 / n_s (Eq. 1, 6), P_l = e_l / e_l(0) (Eq. 2, with
e_l,max = e_l(0), the error with no anchors) and P_s = w_v P_v - w_l P_l (Eq. 3);
the selection maximises P_s over the plans that keep the swarm connected (Eq. 4).

The outer loop is a two-stage search: every feasible n_a is first scored with its
heuristic plan (one Monte Carlo candidate each), then the genetic inner loop refines
the ``refine`` most promising counts. Counts with many steps (n_a close to n_r) cost
n_s Monte Carlo steps per candidate, so screening them once keeps a selection for
large swarms affordable while the search effort goes where P_s can be won.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from coordinator.plan import Plan, feasible_anchor_counts, speed_performance
from coordinator.selection.genetic import GeneticConfig, genetic_search
from coordinator.selection.heuristic import heuristic_plan
from coordinator.selection.monte_carlo import MonteCarlo, plan_keeps_connectivity
from runtime.config import ModelConfig
from runtime.errors import SwarmInputError
from runtime.state import SwarmEstimate


class NoFeasiblePlanError(SwarmInputError):
    """No anchor count and choice keeps every robot observable after every step."""


@dataclass(frozen=True)
class SelectionConfig:
    """Weights of Eq. 3 and the search budget."""

    w_v: float = 0.5
    w_l: float = 0.5
    samples: int = 16  # Monte Carlo samples per candidate for a 10-robot swarm (see ``samples_for``)
    genetic: GeneticConfig = field(default_factory=GeneticConfig)
    anchor_counts: tuple[int, ...] | None = None  # None = every feasible n_a (Eq. 7)
    refine: int = 2  # anchor counts refined by the genetic search after screening (0 = heuristic only)

    def __post_init__(self) -> None:
        if not (self.w_v >= 0 and self.w_l >= 0 and abs(self.w_v + self.w_l - 1.0) < 1e-9):
            raise SwarmInputError(f"weights must be >= 0 and sum to 1 (Eq. 3), got w_v={self.w_v}, w_l={self.w_l}")
        if self.samples < 1:
            raise SwarmInputError(f"Monte Carlo samples must be >= 1, got {self.samples}")


def samples_for(samples: int, n_robots: int) -> int:
    """Monte Carlo samples for ``n_robots``: ``samples`` x 10 / n_r, at least 2.

    e_l (Eq. 8) averages over the robots, so its Monte Carlo standard error falls like
    1 / sqrt(samples x n_r); keeping samples x n_r constant keeps the precision of the
    comparison between plans while a 100-robot selection stays affordable.
    """
    return max(2, -(-samples * 10 // n_robots))


@dataclass(frozen=True)
class CountScore:
    """Outer-loop entry for one anchor count."""

    n_anchors: int
    e_l: float
    p_v: float
    p_l: float
    p_s: float
    plan: Plan | None


@dataclass(frozen=True)
class Selection:
    plan: Plan
    scores: list[CountScore]
    evaluations: int

    @property
    def n_anchors(self) -> int:
        return self.plan.n_anchors


class AnchorSelector:
    """Online selection of (n_a, R_a)* for each configuration change (Section 4)."""

    def __init__(self, cfg: ModelConfig, localizer: str, selection: SelectionConfig, seed: int) -> None:
        self.cfg = cfg
        self.localizer = localizer
        self.selection = selection
        self.seed = seed
        self.calls = 0

    def candidate_counts(self, n: int) -> list[int]:
        feasible = feasible_anchor_counts(n)
        if self.selection.anchor_counts is None:
            return feasible
        bad = [k for k in self.selection.anchor_counts if k not in feasible]
        if bad:
            raise SwarmInputError(f"anchor counts {bad} are not feasible for {n} robots; feasible: {feasible} (Eq. 7)")
        return list(self.selection.anchor_counts)

    def select(self, estimate: SwarmEstimate, desired: np.ndarray) -> Selection:
        """The plan maximising P_s for moving from ``estimate`` to ``desired`` positions (n, 2)."""
        n = estimate.n
        self.calls += 1
        rng = np.random.default_rng([self.seed, self.calls])
        mc = MonteCarlo(self.cfg, self.localizer, samples_for(self.selection.samples, n), int(rng.integers(2**63)))
        current = estimate.positions

        def feasible(plan: Plan) -> bool:
            return plan_keeps_connectivity(plan, current, desired, self.cfg.sensing_range_m)

        def evaluate(plans: list[Plan]) -> np.ndarray:
            return mc.localization_errors(estimate, desired, plans)

        def score(n_a: int, plan: Plan | None, e_l: float) -> CountScore:
            p_v = speed_performance(n, n_a)
            p_l = e_l / e_max if e_max > 0 else 0.0
            return CountScore(n_a, float(e_l), p_v, float(p_l), float(self.selection.w_v * p_v - self.selection.w_l * p_l), plan)

        all_move = Plan.equal(np.arange(n), 0)
        e_max = float(evaluate([all_move])[0])  # e_l,max = e_l(0) (Section 4.1.1)
        evaluations = 1
        scores: dict[int, CountScore] = {}
        for n_a in self.candidate_counts(n):  # stage 1: heuristic plan of every count
            plan = all_move if n_a == 0 else heuristic_plan(current, desired, n_a)
            if not feasible(plan):
                scores[n_a] = score(n_a, None, np.inf)
            elif n_a == 0:
                scores[n_a] = score(n_a, plan, e_max)
            else:
                scores[n_a] = score(n_a, plan, float(evaluate([plan])[0]))
                evaluations += 1
        ranked = sorted((k for k in scores if k != 0), key=lambda k: -scores[k].p_s if scores[k].plan else np.inf)
        for n_a in ranked[: self.selection.refine]:  # stage 2: genetic search where P_s can be won
            seed = scores[n_a].plan or heuristic_plan(current, desired, n_a)
            known = {seed.key(): scores[n_a].e_l}
            plan, e_l, k = genetic_search(evaluate, [seed], feasible, rng, self.selection.genetic, known)
            evaluations += k
            if plan is not None and e_l <= scores[n_a].e_l:
                scores[n_a] = score(n_a, plan, e_l)
        ordered = [scores[k] for k in sorted(scores)]
        best = max((s for s in ordered if s.plan is not None), key=lambda s: s.p_s, default=None)
        if best is None:
            raise NoFeasiblePlanError(
                f"no anchor plan keeps every robot within sensing range {self.cfg.sensing_range_m} m of another "
                f"after every step (tried n_a = {sorted(scores)})"
            )
        return Selection(best.plan, ordered, evaluations)
