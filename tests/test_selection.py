"""Anchor selection: Monte Carlo with common random numbers, genetic search vs exhaustive, constraints."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from coordinator.plan import Plan, feasible_anchor_counts
from coordinator.selection.genetic import GeneticConfig, genetic_search
from coordinator.selection.heuristic import heuristic_plan
from coordinator.selection.monte_carlo import MonteCarlo, plan_keeps_connectivity
from coordinator.selection.selector import AnchorSelector, NoFeasiblePlanError, SelectionConfig
from runtime.config import ModelConfig
from runtime.state import SwarmEstimate
from runtime.trajectory import random_trajectory


def step_problem(n: int, seed: int) -> tuple[SwarmEstimate, np.ndarray]:
    traj = random_trajectory(n, 1, np.random.default_rng(seed))
    return SwarmEstimate.isotropic(traj.ids, traj.initial_poses, 0.01, math.radians(2)), traj.configurations[0]


def all_plans(n: int, n_a: int) -> list[Plan]:
    """Every ordered partition into equal groups (Eq. 10)."""
    size = n - n_a
    plans = []

    def extend(prefix: list[int], rest: list[int]) -> None:
        if not rest:
            plans.append(Plan.equal(np.array(prefix), n_a))
            return
        for group in itertools.combinations(rest, size):
            extend(prefix + list(group), [r for r in rest if r not in group])

    extend([], list(range(n)))
    return plans


def test_batch_evaluation_uses_common_random_numbers():
    estimate, desired = step_problem(6, 1)
    mc = MonteCarlo(ModelConfig(), "paper", 6, seed=11)
    plans = all_plans(6, 3)[:5]
    together = mc.localization_errors(estimate, desired, plans)
    alone = np.array([mc.localization_errors(estimate, desired, [p])[0] for p in plans])
    np.testing.assert_allclose(together, alone, rtol=1e-9)
    assert len(set(np.round(together, 12))) > 1  # plans do differ


@pytest.mark.parametrize("n_a,seed", [(3, 0), (4, 1), (4, 2)])
def test_genetic_search_is_within_5_percent_of_exhaustive_optimum(n_a, seed):
    estimate, desired = step_problem(6, seed)
    mc = MonteCarlo(ModelConfig(), "paper", 8, seed=seed)
    plans = [p for p in all_plans(6, n_a) if plan_keeps_connectivity(p, estimate.positions, desired, 0.5)]
    optimum = float(np.min(mc.localization_errors(estimate, desired, plans)))

    def feasible(p: Plan) -> bool:
        return plan_keeps_connectivity(p, estimate.positions, desired, 0.5)

    def evaluate(ps: list[Plan]) -> np.ndarray:
        return mc.localization_errors(estimate, desired, ps)

    seed_plan = heuristic_plan(estimate.positions, desired, n_a)
    best, e_l, evaluated = genetic_search(evaluate, [seed_plan], feasible, np.random.default_rng(seed), GeneticConfig())
    assert best is not None
    assert e_l <= 1.05 * optimum
    assert evaluated <= len(plans) or n_a == 3


def test_selection_is_reproducible_from_its_seed():
    estimate, desired = step_problem(6, 3)
    config = SelectionConfig(samples=4, genetic=GeneticConfig(population=6, generations=3))
    a = AnchorSelector(ModelConfig(), "paper", config, seed=5).select(estimate, desired)
    b = AnchorSelector(ModelConfig(), "paper", config, seed=5).select(estimate, desired)
    assert a.plan.key() == b.plan.key()
    assert [s.e_l for s in a.scores] == [s.e_l for s in b.scores]
    assert [s.n_anchors for s in a.scores] == feasible_anchor_counts(6)
    assert a.scores[0].p_l == 1.0 and a.scores[0].p_v == 1.0  # n_a = 0 defines e_l,max and v_max


def test_heuristic_only_selection_known_answer():
    """One anchor count and no refinement: the plan is exactly the heuristic plan of Eq. 11-13, found with
    two Monte Carlo evaluations (e_l,max with no anchors, then the heuristic plan), and its scores follow
    Eq. 1-3 (n_r = 6, n_a = 3: n_s = 2, P_v = 1/2; P_s = 0.5 x 1/2 - 0.5 x e_l / e_l(0))."""
    estimate, desired = step_problem(6, 3)
    config = SelectionConfig(samples=4, anchor_counts=(3,), refine=0)
    selection = AnchorSelector(ModelConfig(), "paper", config, seed=5).select(estimate, desired)
    assert selection.plan.key() == heuristic_plan(estimate.positions, desired, 3).key()
    assert selection.evaluations == 2 and [s.n_anchors for s in selection.scores] == [3]
    (score,) = selection.scores
    assert score.p_v == 0.5 and score.p_s == pytest.approx(0.25 - 0.5 * score.p_l, abs=1e-15) and score.p_l > 0


def test_weights_move_the_choice_towards_speed_or_accuracy():
    estimate, desired = step_problem(6, 4)
    budget = dict(samples=4, genetic=GeneticConfig(population=6, generations=2))
    fast = AnchorSelector(ModelConfig(), "paper", SelectionConfig(w_v=1.0, w_l=0.0, **budget), seed=1).select(estimate, desired)
    careful = AnchorSelector(ModelConfig(), "paper", SelectionConfig(w_v=0.0, w_l=1.0, **budget), seed=1).select(estimate, desired)
    assert fast.n_anchors == 0
    assert careful.n_anchors > 0


def test_connectivity_constraint_known_case():
    current = np.array([[0.0, 0.0], [0.4, 0.0], [0.8, 0.0]])
    desired = np.array([[0.0, 0.4], [2.0, 0.0], [0.8, 0.4]])  # robot 1 leaves: 0 and 2 lose each other
    assert not plan_keeps_connectivity(Plan(np.array([1, 0, 2]), (1, 1, 1)), current, desired, 0.5)
    desired_ok = np.array([[0.0, 0.25], [0.4, 0.25], [0.8, 0.25]])
    assert plan_keeps_connectivity(Plan(np.array([1, 0, 2]), (1, 1, 1)), current, desired_ok, 0.5)


def test_no_feasible_plan_is_said_clearly():
    estimate = SwarmEstimate.isotropic([0, 1, 2, 3], np.array([[0, 0, 0], [0.3, 0, 0], [0, 0.3, 0], [0.3, 0.3, 0]], float), 0.01, 0.02)
    desired = np.array([[0, 0], [0.3, 0], [5, 5], [5.3, 5]], float)  # two groups 7 m apart
    with pytest.raises(NoFeasiblePlanError, match="no anchor plan keeps every robot within sensing range"):
        AnchorSelector(ModelConfig(), "paper", SelectionConfig(samples=2), seed=0).select(estimate, desired)
