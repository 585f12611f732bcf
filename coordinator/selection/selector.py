"""Outer loop of the anchor selection (Section 4.2.1, Fig. 6): the number of anchors.

For every feasible anchor count n_a (Eq. 7) the inner loop finds the anchors R_a*(n_a)
with the least expected localization error e_l (Eq. 9), seeded by the heuristic
(Eq. 11-13). Then P_v = 1 / n_s (Eq. 1, 6), P_l = e_l / e_l(0) (Eq. 2, with
e_l,max = e_l(0), the error with no anchors) and P_s = w_v P_v - w_l P_l (Eq. 3);
the selection maximises P_s over the plans that keep the swarm connected (Eq. 4).
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
    samples: int = 16  # Monte Carlo samples per candidate
    genetic: GeneticConfig = field(default_factory=GeneticConfig)
    anchor_counts: tuple[int, ...] | None = None  # None = every feasible n_a (Eq. 7)
    search: bool = True  # False = heuristic plan only

    def __post_init__(self) -> None:
        if not (self.w_v >= 0 and self.w_l >= 0 and abs(self.w_v + self.w_l - 1.0) < 1e-9):
            raise SwarmInputError(f"weights must be >= 0 and sum to 1 (Eq. 3), got w_v={self.w_v}, w_l={self.w_l}")
        if self.samples < 1:
            raise SwarmInputError(f"Monte Carlo samples must be >= 1, got {self.samples}")


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
        mc = MonteCarlo(self.cfg, self.localizer, self.selection.samples, int(rng.integers(2**63)))
        current = estimate.positions

        def feasible(plan: Plan) -> bool:
            return plan_keeps_connectivity(plan, current, desired, self.cfg.sensing_range_m)

        def evaluate(plans: list[Plan]) -> np.ndarray:
            return mc.localization_errors(estimate, desired, plans)

        all_move = Plan.equal(np.arange(n), 0)
        e_max = float(evaluate([all_move])[0])  # e_l,max = e_l(0) (Section 4.1.1)
        scores, evaluations = [], 1
        for n_a in self.candidate_counts(n):
            if n_a == 0:
                plan, e_l = (all_move, e_max) if feasible(all_move) else (None, np.inf)
            elif self.selection.search:
                seed_plan = heuristic_plan(current, desired, n_a)
                plan, e_l, k = genetic_search(evaluate, [seed_plan], feasible, rng, self.selection.genetic)
                evaluations += k
            else:
                plan = heuristic_plan(current, desired, n_a)
                e_l = float(evaluate([plan])[0]) if feasible(plan) else np.inf
                plan = plan if np.isfinite(e_l) else None
                evaluations += 1
            p_v = speed_performance(n, n_a)
            p_l = e_l / e_max if e_max > 0 else 0.0
            p_s = self.selection.w_v * p_v - self.selection.w_l * p_l
            scores.append(CountScore(n_a, float(e_l), p_v, float(p_l), float(p_s), plan))
        best = max((s for s in scores if s.plan is not None), key=lambda s: s.p_s, default=None)
        if best is None:
            raise NoFeasiblePlanError(
                f"no anchor plan keeps every robot within sensing range {self.cfg.sensing_range_m} m of another "
                f"after every step (tried n_a = {[s.n_anchors for s in scores]})"
            )
        return Selection(best.plan, scores, evaluations)
