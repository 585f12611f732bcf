"""Feasible anchor counts, plan validity, heuristic and genetic operators (property-based where it fits)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from coordinator.plan import Plan, feasible_anchor_counts, n_solutions, n_steps, speed_performance
from coordinator.selection.genetic import GeneticConfig, genetic_search, order_crossover, swap_mutation
from coordinator.selection.heuristic import heuristic_plan, step_score
from runtime.errors import SwarmInputError


def test_feasible_counts_eq7_examples():
    assert feasible_anchor_counts(10) == [0, 5, 8, 9]
    assert feasible_anchor_counts(6) == [0, 3, 4, 5]
    assert n_steps(10, 8) == 5
    assert speed_performance(10, 5) == 0.5


@given(st.integers(2, 200))
def test_feasible_counts_give_integer_steps(n):
    counts = feasible_anchor_counts(n)
    assert counts[0] == 0 and counts[-1] == n - 1
    for n_a in range(n):
        assert (n_a in counts) == (n % (n - n_a) == 0)


def test_n_solutions_eq10():
    assert n_solutions(10, 5) == math.comb(10, 5)
    assert n_solutions(10, 9) == math.factorial(10)
    assert n_solutions(6, 4) == 90


def test_infeasible_count_is_rejected():
    with pytest.raises(SwarmInputError, match="7 anchors is not feasible for 10 robots"):
        n_steps(10, 7)


@st.composite
def permutations_and_counts(draw):
    n = draw(st.integers(2, 30))
    n_a = draw(st.sampled_from(feasible_anchor_counts(n)))
    seed = draw(st.integers(0, 2**32 - 1))
    return n, n_a, np.random.default_rng(seed)


@settings(max_examples=200, deadline=None)
@given(permutations_and_counts())
def test_genetic_operators_keep_valid_partitions(args):
    n, n_a, rng = args
    a = Plan.equal(rng.permutation(n), n_a)
    b = Plan.equal(rng.permutation(n), n_a)
    child = Plan(order_crossover(a.order, b.order, rng), a.sizes)  # Plan validates the permutation
    mutated = Plan(swap_mutation(child.order, child.sizes, rng), child.sizes)
    groups = mutated.groups
    assert len(groups) == n_steps(n, n_a) and all(len(g) == n - n_a for g in groups)
    assert sorted(np.concatenate(groups).tolist()) == list(range(n))
    if len(groups) > 1:
        assert mutated.key() != child.key()  # a swap across groups always changes the partition
    for k in range(mutated.n_steps):
        assert mutated.moving(k).sum() == n - n_a


def test_plan_rejects_non_partitions():
    with pytest.raises(SwarmInputError, match="permutation"):
        Plan(np.array([0, 0, 1]), (3,))
    with pytest.raises(SwarmInputError, match="do not partition"):
        Plan(np.arange(4), (3,))


def test_heuristic_prefers_spread_anchors_close_to_movers():
    # A ring of 4 robots around 4 central robots; all move a little to the right.
    ring = [[1, 0], [0, 1], [-1, 0], [0, -1]]
    centre = [[0.1, 0], [0, 0.1], [-0.1, 0], [0, -0.1]]
    current = np.array(ring + centre, float)
    desired = current + [0.05, 0.0]
    plan = heuristic_plan(current, desired, 4)
    assert sorted(plan.groups[0].tolist()) == [4, 5, 6, 7]  # the centre moves first, the ring anchors


def test_step_score_is_eq13():
    base = np.array([[0, 0], [2, 0], [1, 1]], float)
    desired = base + [0, 3]
    group = np.array([[False, False, True]])
    d = 1.0  # anchors at (0,0), (2,0): centroid (1,0), both 1 m away
    s = 4.0  # mobile centroid (1, 4)
    assert step_score(group, base, desired)[0] == pytest.approx(d + 1 / s)


def test_genetic_search_finds_the_known_optimum_and_respects_feasibility():
    n, n_a = 8, 6
    rng = np.random.default_rng(0)
    target = Plan.equal(np.array([3, 5, 0, 7, 1, 2, 4, 6]), n_a)
    target_groups = target.groups

    def evaluate(plans):
        return np.array([sum(len(set(g) ^ set(t)) for g, t in zip(p.groups, target_groups, strict=True)) for p in plans], float)

    def feasible(plan):  # robot 6 may never move first
        return 6 not in plan.groups[0]

    best, e, evaluations = genetic_search(evaluate, [Plan.equal(rng.permutation(n), n_a)], feasible, rng,
                                          GeneticConfig(population=30, generations=60, patience=60))
    assert e == 0.0 and best.key() == target.key()
    assert evaluations < n_solutions(n, n_a)

    _, e_none, _ = genetic_search(evaluate, [Plan.equal(np.arange(n), n_a)], lambda p: False, rng)
    assert e_none == np.inf


def test_plan_normalises_its_encoding():
    """A plan given as floats and lists is stored as an int64 permutation and a tuple of ints.

    By hand: order (2, 0, 1) cut into sizes (1, 2) gives groups [2] and [0, 1]; step 0 moves
    robot 2 only, step 1 robots 0 and 1. The masks index arrays (a float mask or float group
    indices could not), and the stored sizes compare equal to the tuple (1, 2).
    """
    plan = Plan([2.0, 0.0, 1.0], [np.int32(1), 2])
    assert isinstance(plan.order, np.ndarray) and plan.order.dtype == np.int64
    assert plan.order.tolist() == [2, 0, 1]
    assert plan.sizes == (1, 2) and all(type(s) is int for s in plan.sizes)
    assert [g.tolist() for g in plan.groups] == [[2], [0, 1]]
    assert plan.moving(0).dtype == bool and plan.moving(0).tolist() == [False, False, True]
    assert np.array([10, 11, 12])[plan.moving(1)].tolist() == [10, 11]
    assert (plan.n_robots, plan.n_steps, plan.n_anchors) == (3, 2, 2)
    assert plan.key() == ((2,), (0, 1))
