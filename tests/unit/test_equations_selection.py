"""Known answers for the anchor selection (Eq. 1-4, 6, 7, 10-13): coordinator/plan.py, selection/heuristic.py, selector.py.

Every number below is derived by hand in the test's docstring, on inputs where a wrong
weight, sum/mean, axis or sign gives a different one.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from coordinator.localization import make_localizer
from coordinator.plan import Plan, feasible_anchor_counts, n_solutions, n_steps, speed_performance
from coordinator.selection.genetic import GeneticConfig
from coordinator.selection.heuristic import MIN_SEPARATION, heuristic_plan, step_score
from coordinator.selection.monte_carlo import plan_keeps_connectivity
from coordinator.selection.selector import AnchorSelector, SelectionConfig, samples_for
from runtime.errors import SwarmInputError
from runtime.models.config import ModelConfig
from runtime.models.state import SwarmEstimate

# -- Eq. 1, 6, 7, 10 ----------------------------------------------------------------


def test_eq7_feasible_anchor_counts_of_12_robots():
    """n_s = n_r / (n_r - n_a) must be an integer (Eq. 7).

    n_r = 12: n_m = n_r - n_a must divide 12, so n_m in {12, 6, 4, 3, 2, 1} and
    n_a in {0, 6, 8, 9, 10, 11}; n_a = 7 (n_m = 5) and n_a = 1 (n_m = 11) are not feasible.
    """
    assert feasible_anchor_counts(12) == [0, 6, 8, 9, 10, 11]
    assert feasible_anchor_counts(1) == [0]
    assert feasible_anchor_counts(7) == [0, 6]  # a prime: everyone or one at a time


@pytest.mark.parametrize("n_r,n_a,steps", [(12, 0, 1), (12, 6, 2), (12, 8, 3), (12, 9, 4), (12, 10, 6), (12, 11, 12)])
def test_eq6_eq7_steps_and_speed_performance(n_r, n_a, steps):
    """n_s = n_r / (n_r - n_a) (Eq. 7), v = 1 / n_s (Eq. 6), v_max = v(0) = 1, so P_v = 1 / n_s (Eq. 1).

    n_r = 12: n_a = 8 -> n_s = 12 / 4 = 3, P_v = 1/3; n_a = 10 -> 12 / 2 = 6, P_v = 1/6.
    """
    assert n_steps(n_r, n_a) == steps
    assert speed_performance(n_r, n_a) == pytest.approx(1.0 / steps, abs=1e-15)


@pytest.mark.parametrize("n_a", [1, 7])
def test_eq7_infeasible_counts_are_refused(n_a):
    with pytest.raises(SwarmInputError, match=f"{n_a} anchors is not feasible for 12 robots"):
        n_steps(12, n_a)


@pytest.mark.parametrize("n_r,n_a,expected", [
    (12, 8, 495 * 70 * 1),  # n_m = 4: C(12,4) C(8,4) C(4,4) = 495 x 70 x 1 = 34650
    (6, 4, 15 * 6 * 1),  # n_m = 2: C(6,2) C(4,2) C(2,2) = 15 x 6 x 1 = 90
    (6, 3, 20 * 1),  # n_m = 3: C(6,3) C(3,3) = 20
    (9, 6, 84 * 20 * 1),  # n_m = 3: C(9,3) C(6,3) C(3,3) = 84 x 20 x 1 = 1680
    (5, 0, 1),  # everyone moves at once: one plan
])
def test_eq10_number_of_solutions(n_r, n_a, expected):
    """n_sol = prod_{k=0}^{n_s-1} C(n - k n_m, n_m) (Eq. 10), expanded by hand per case."""
    assert n_solutions(n_r, n_a) == expected


def test_plan_groups_masks_and_canonical_key():
    """Order (2, 0, 5, 1, 3, 4) cut into sizes (1, 2, 3): groups [2], [0, 5], [1, 3, 4].

    The largest step has 6 - 1 = 5 anchors; step 1 moves robots 0 and 5; the key sorts each group.
    """
    plan = Plan(np.array([2, 0, 5, 1, 3, 4]), (1, 2, 3))
    assert [g.tolist() for g in plan.groups] == [[2], [0, 5], [1, 3, 4]]
    assert plan.n_robots == 6 and plan.n_steps == 3 and plan.n_anchors == 5
    assert plan.moving(1).tolist() == [True, False, False, False, False, True]
    assert plan.moving(2).tolist() == [False, True, False, True, True, False]
    assert plan.key() == ((2,), (0, 5), (1, 3, 4))
    assert Plan(np.array([2, 5, 0, 4, 3, 1]), (1, 2, 3)).key() == plan.key()
    equal = Plan.equal(np.array([3, 1, 0, 2, 5, 4]), 4)  # n_m = 2, n_s = 3
    assert equal.sizes == (2, 2, 2) and [g.tolist() for g in equal.groups] == [[3, 1], [0, 2], [5, 4]]


@pytest.mark.parametrize("order,sizes,message", [
    ([0, 1, 1], (3,), r"a plan's order must be a permutation of 0\.\.2, got \[0, 1, 1\]"),
    ([0, 1, 3], (3,), r"permutation of 0\.\.2, got \[0, 1, 3\]"),
    ([0, 1, 2], (2, 2), r"group sizes \(2, 2\) do not partition 3 robots"),
    ([0, 1, 2], (3, 0), r"group sizes \(3, 0\) do not partition 3 robots"),
])
def test_plan_refuses_what_is_not_an_ordered_partition(order, sizes, message):
    with pytest.raises(SwarmInputError, match=message):
        Plan(np.array(order), sizes)


# -- Eq. 11-13 -----------------------------------------------------------------------

# Candidate scores: base (expected positions of robots that stand still) and desired positions.
BASE = np.array([[-1.0, 0.0], [1.0, 0.0], [0.0, 3.0], [9.0, 9.0], [9.0, -9.0]])
DESIRED = np.array([[5.0, 0.0], [5.0, 2.0], [0.0, 0.0], [0.0, 1.5], [1.0, 1.5]])


def test_eq11_to_13_step_score_known_answers():
    """p = d + 1/s (Eq. 13) for two candidate mobile groups of 5 robots.

    Group {3, 4} moves, anchors 0, 1, 2 at (-1,0), (1,0), (0,3): centroid (0, 1); distances
    sqrt(2), sqrt(2), 2, so d = (2 sqrt(2) + 2) / 3 (Eq. 11; their sum would be 3x that).
    The movers' centroid at their *desired* positions (0,1.5), (1,1.5) is (0.5, 1.5)
    (their base positions would give (9, 0)); s = |(0.5, 0.5)| = sqrt(0.5) (Eq. 12), 1/s = sqrt(2).
    p = (2 sqrt(2) + 2)/3 + sqrt(2) = 3.0237.

    Group {0, 1} moves, anchors 2, 3, 4 at (0,3), (9,9), (9,-9): centroid (6, 1); distances
    sqrt(40), sqrt(73), sqrt(109): d = (sqrt(40) + sqrt(73) + sqrt(109)) / 3; movers' desired
    centroid (5, 1): s = 1; p = d + 1 = 9.4363.
    """
    masks = np.array([[False, False, False, True, True], [True, True, False, False, False]])
    p = step_score(masks, BASE, DESIRED)
    expected = [
        (2 * math.sqrt(2) + 2) / 3 + math.sqrt(2),
        (math.sqrt(40) + math.sqrt(73) + math.sqrt(109)) / 3 + 1.0,
    ]
    np.testing.assert_allclose(p, expected, rtol=0, atol=1e-12)


def test_eq11_to_13_single_anchor():
    """One anchor at (3, 4) (robots 1, 2 move, desired at (0, 0) and (0, 2)): d = 0 (Eq. 11 of one point),
    its centroid is itself, the movers' centroid (0, 1), s = |(3, 3)| = 3 sqrt(2), p = 1 / (3 sqrt(2))."""
    base = np.array([[3.0, 4.0], [8.0, 8.0], [9.0, 9.0]])
    desired = np.array([[5.0, 5.0], [0.0, 0.0], [0.0, 2.0]])
    p = step_score(np.array([[False, True, True]]), base, desired)
    assert p[0] == pytest.approx(1.0 / (3.0 * math.sqrt(2.0)), rel=1e-12)


def test_eq12_zero_separation_is_floored_not_infinite():
    """Anchors (0,0), (2,0) (centroid (1,0), d = 1) and a mover desired at (1,0): s = 0 -> 1/MIN_SEPARATION."""
    base = np.array([[0.0, 0.0], [2.0, 0.0], [7.0, 7.0]])
    desired = np.array([[0.0, 0.0], [2.0, 0.0], [1.0, 0.0]])
    p = step_score(np.array([[False, False, True]]), base, desired)
    assert MIN_SEPARATION == 1e-9
    assert p[0] == pytest.approx(1.0 + 1e9, rel=1e-12)


def test_eq11_to_13_heuristic_three_step_plan_moves_earlier_movers_first():
    """3 robots, n_a = 2: three steps of one mover, each maximising p = d + 1/s (Eq. 13).

    current r0 (0,0), r1 (2,0), r2 (0,2); desired r0 (1,2), r1 (-1,0), r2 (4,3).
    Step 1 (everyone at current positions):
      move r0: anchors r1, r2, centroid (1,1), d = sqrt(2); s = |(1,1)-(1,2)| = 1; p = 2.414
      move r1: anchors r0, r2, centroid (0,1), d = 1; s = |(0,1)-(-1,0)| = sqrt(2); p = 1.707
      move r2: anchors r0, r1, centroid (1,0), d = 1; s = |(1,0)-(4,3)| = 3 sqrt(2); p = 1.236
      -> r0 moves, and is expected at its desired (1,2) from now on.
    Step 2:
      move r1: anchors r0 (1,2), r2 (0,2), centroid (0.5,2), d = 0.5; s = |(1.5,2)| = 2.5; p = 0.9
      move r2: anchors r0 (1,2), r1 (2,0), centroid (1.5,1), d = sqrt(1.25) = 1.118;
               s = |(2.5,2)| = sqrt(10.25) = 3.202; p = 1.430
      -> r2, then r1. Had r0 been left at (0,0), step 2 would repeat step 1's scores
      (1.707 for r1 > 1.236 for r2) and the plan would be r0, r1, r2.
    """
    current = np.array([[0.0, 0.0], [2.0, 0.0], [0.0, 2.0]])
    desired = np.array([[1.0, 2.0], [-1.0, 0.0], [4.0, 3.0]])
    plan = heuristic_plan(current, desired, 2)
    assert [g.tolist() for g in plan.groups] == [[0], [2], [1]]


def test_eq11_to_13_heuristic_three_groups_of_two():
    """6 robots, n_a = 4: three steps of two movers; the first two groups by Eq. 13, the last is the rest.

    Robots 0..5 at x = 0..5 (y = 0); desired: 0 (0,20), 1 (2.4,0.1), 2 (2,10), 3 (3,10), 4 (2.6,0.1), 5 (5,20).
    Step 1, movers {1, 4}: anchors 0, 2, 3, 5, centroid (2.5, 0), d = (2.5 + 0.5 + 0.5 + 2.5)/4 = 1.5;
      movers' desired centroid (2.5, 0.1), s = 0.1: p = 11.5. Next best {2, 3}: anchors at x = 0, 1, 4, 5,
      d = (2.5 + 1.5 + 1.5 + 2.5)/4 = 2, s = |(2.5,0) - (2.5,10)| = 10, p = 2.1.
    Step 2 (1 and 4 now at (2.4, 0.1) and (2.6, 0.1)), pairs of the pool {0, 2, 3, 5}:
      {2, 3}: anchors (0,0), (2.4,0.1), (2.6,0.1), (5,0), centroid (2.5, 0.05),
              d = (2 sqrt(2.5^2 + 0.05^2) + 2 sqrt(0.1^2 + 0.05^2))/4 = 1.3062, s = 10 - 0.05, p = 1.4067;
      {0, 5}: anchors (2.4,0.1), (2,0), (3,0), (2.6,0.1), centroid (2.5, 0.05),
              d = (2 sqrt(0.1^2 + 0.05^2) + 2 sqrt(0.5^2 + 0.05^2))/4 = 0.3071, s = 19.95, p = 0.3573;
      {0, 3} and {2, 5} (mirror images): p = 1.0683; {0, 2} and {3, 5}: p = 0.9434.
      -> {2, 3}, then {0, 5}.
    """
    current = np.array([[x, 0.0] for x in range(6)])
    desired = np.array([[0.0, 20.0], [2.4, 0.1], [2.0, 10.0], [3.0, 10.0], [2.6, 0.1], [5.0, 20.0]])
    plan = heuristic_plan(current, desired, 4)
    assert plan.key() == ((1, 4), (2, 3), (0, 5))
    assert plan.order.tolist() == [1, 4, 2, 3, 0, 5]  # each group in ascending robot order


def _p_by_hand(base: np.ndarray, desired: np.ndarray, movers: list[int]) -> float:
    """Eq. 11-13 for one group, written out with plain loops."""
    anchors = [i for i in range(len(base)) if i not in movers]
    ca = sum(base[i] for i in anchors) / len(anchors)
    d = sum(math.dist(base[i], ca) for i in anchors) / len(anchors)
    cm = sum(desired[i] for i in movers) / len(movers)
    return d + 1.0 / math.dist(ca, cm)


def test_heuristic_large_pool_swap_search_ends_in_a_local_optimum():
    """Above ENUMERATE_LIMIT candidate groups (C(16, 8) = 12870) the group is improved by single swaps.

    The first group returned must score at least as high (Eq. 13, computed here by hand) as its
    start (the 8 robots desired nearest the centroid) and as every group one swap away.
    """
    rng = np.random.default_rng(3)
    current = rng.uniform(0, 2, (16, 2))
    desired = current + rng.normal(0, 0.4, (16, 2))
    plan = heuristic_plan(current, desired, 8)
    first = sorted(plan.groups[0].tolist())
    got = _p_by_hand(current, desired, first)
    start = np.argsort(np.linalg.norm(desired - current.mean(axis=0), axis=1), kind="stable")[:8].tolist()
    assert got >= _p_by_hand(current, desired, start) - 1e-12
    outside = [r for r in range(16) if r not in first]
    for a, b in itertools.product(first, outside):
        neighbour = [b if r == a else r for r in first]
        assert _p_by_hand(current, desired, neighbour) <= got + 1e-12
    assert plan.n_steps == 2 and sorted(plan.order.tolist()) == list(range(16))


# -- Eq. 2-4 (outer loop) -------------------------------------------------------------


def _line_problem() -> tuple[SwarmEstimate, np.ndarray]:
    """6 robots 0.2 m apart on two rows, desired 0.1 m to the right."""
    poses = np.array([[0.2 * (i % 3), 0.2 * (i // 3), 0.0] for i in range(6)])
    estimate = SwarmEstimate.isotropic(np.arange(6), poses, 0.01, math.radians(2))
    return estimate, poses[:, :2] + [0.1, 0.0]


def test_eq1_to_3_outer_loop_scores():
    """P_v = 1/n_s (Eq. 1, 6), P_l = e_l / e_l(0) (Eq. 2), P_s = w_v P_v - w_l P_l (Eq. 3), best = max P_s.

    Unequal weights w_v = 0.3, w_l = 0.7 (swapping them, or a + for the -, changes P_s).
    n_r = 6: feasible n_a = 0, 3, 4, 5 with n_s = 1, 2, 3, 6, so P_v = 1, 1/2, 1/3, 1/6;
    n_a = 0 defines e_l,max, so its P_l = 1 and P_s = 0.3 - 0.7 = -0.4.
    """
    estimate, desired = _line_problem()
    selection = SelectionConfig(w_v=0.3, w_l=0.7, samples=4, genetic=GeneticConfig(population=4, generations=1))
    result = AnchorSelector(ModelConfig(), make_localizer("paper", ModelConfig()), selection, seed=2).select(estimate, desired)
    scores = {s.n_anchors: s for s in result.scores}
    assert sorted(scores) == [0, 3, 4, 5]
    e_max = scores[0].e_l
    assert e_max > 0
    for n_a, p_v in ((0, 1.0), (3, 0.5), (4, 1 / 3), (5, 1 / 6)):
        s = scores[n_a]
        assert s.p_v == pytest.approx(p_v, abs=1e-15)
        if not s.searched:  # screened only: e_l and e_l(0) from the same screening samples
            assert s.p_l == pytest.approx(s.e_l / e_max, rel=1e-12)
        # (a searched count's P_l divides by e_l(0) on its final fresh set: docs/selection.md)
        assert s.p_s == pytest.approx(0.3 * p_v - 0.7 * s.p_l, rel=1e-12, abs=1e-15)
    assert scores[0].p_l == 1.0 and scores[0].p_s == pytest.approx(-0.4, abs=1e-15)
    best = max((s for s in result.scores if s.plan is not None), key=lambda s: s.p_s)
    assert result.plan.key() == best.plan.key() and result.n_anchors == best.n_anchors


def test_eq4_disconnecting_counts_are_never_chosen():
    """g <= 0 (Eq. 4): robots 0.4 m apart, sensing 0.5 m, desired positions 0.4 m to the side.

    Robots 0, 1, 2 at x = 0, 0.4, 0.8 must reach y = 0.4. One at a time (n_a = 2: groups of
    one), whichever robot moves first is sqrt(0.4^2 + 0.4^2) = 0.57 m > 0.5 m from its former
    neighbours, so every order breaks the range after step 1; only n_a = 0 (everyone at once,
    the desired row 0.4 m apart is connected) is feasible, so it is chosen even with w_l = 1.
    """
    current = np.array([[0.0, 0.0], [0.4, 0.0], [0.8, 0.0]])
    desired = current + [0.0, 0.4]
    for order in itertools.permutations(range(3)):
        assert not plan_keeps_connectivity(Plan(np.array(order), (1, 1, 1)), current, desired, 0.5)
    assert plan_keeps_connectivity(Plan(np.arange(3), (3,)), current, desired, 0.5)
    estimate = SwarmEstimate.isotropic(np.arange(3), np.c_[current, np.zeros(3)], 0.01, 0.02)
    result = AnchorSelector(ModelConfig(), make_localizer("paper", ModelConfig()), SelectionConfig(w_v=0.0, w_l=1.0, samples=2),
                            seed=0).select(estimate, desired)
    scores = {s.n_anchors: s for s in result.scores}
    assert scores[2].plan is None and scores[2].e_l == np.inf
    assert result.n_anchors == 0  # even with w_l = 1, where any feasible anchor plan would win


@pytest.mark.parametrize("samples,n_r,expected", [(16, 10, 16), (16, 100, 2), (16, 30, 6), (16, 3, 54), (1, 50, 2)])
def test_monte_carlo_samples_scale_with_swarm_size(samples, n_r, expected):
    """samples x 10 / n_r rounded up, at least 2: 16 x 10 / 30 = 5.33 -> 6; 16 x 10 / 3 = 53.3 -> 54."""
    assert samples_for(samples, n_r) == expected


@pytest.mark.parametrize("w_v,w_l", [(0.6, 0.6), (-0.1, 1.1), (1.2, -0.2)])
def test_eq3_weights_must_be_non_negative_and_sum_to_one(w_v, w_l):
    with pytest.raises(SwarmInputError, match="weights must be >= 0 and sum to 1"):
        SelectionConfig(w_v=w_v, w_l=w_l)
