"""Known answers for the anchor-selection operators (coordinator/selection/): the genetic operators
(OX1 crossover, swap mutation), the genetic search's bookkeeping (cache, elitism, patience),
the Cramer-Rao prediction of e_l (crlb_rank) and the Monte Carlo e_l (Eq. 8) where it has a closed form.

The genetic operators get their random choices from a scripted generator (``Scripted``) so the cut
points and swapped robots are known and the child can be written out by hand; the other answers are
closed forms derived in each docstring. They pin what the operators do, not the search budgets.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from coordinator.localization import make_localizer
from coordinator.localization.registry import BUILTIN_LOCALIZERS
from coordinator.plan import Plan, PlanKey, n_partitions
from coordinator.selection.crlb_rank import MEAN_NORM, predicted_errors
from coordinator.selection.genetic import GeneticConfig, genetic_search, order_crossover, single_swaps, swap_mutation
from coordinator.selection.monte_carlo import MonteCarlo, plan_keeps_connectivity
from runtime.models.config import ModelConfig
from runtime.models.state import SwarmEstimate


class Scripted:
    """The two ``np.random.Generator`` calls the operators make, answering from a script and recording them."""

    def __init__(self, choice=None, integers=None) -> None:
        self._choice, self._integers, self.calls = choice, integers, []

    def choice(self, a, size=None, replace=True):
        self.calls.append(("choice", np.array(a).tolist() if np.ndim(a) else a, size, replace))
        return np.array(self._choice) if size is not None else self._choice

    def integers(self, high):
        self.calls.append(("integers", high))
        return self._integers


def test_order_crossover_by_hand():
    """OX1 with cut points 2 and 5 (drawn in either order from 0..n): the child keeps a[2:5] = (2, 3, 4)
    in place and fills positions 0, 1, 5, 6, 7 with b's other robots in b's order (7, 6, 5, 1, 0):
    child = (7, 6, 2, 3, 4, 5, 1, 0)."""
    a, b = np.arange(8), np.arange(8)[::-1].copy()
    rng = Scripted(choice=[5, 2])
    assert order_crossover(a, b, rng).tolist() == [7, 6, 2, 3, 4, 5, 1, 0]
    assert rng.calls == [("choice", 9, 2, False)]  # cut points 0..n, distinct


def test_order_crossover_whole_and_empty_slices():
    """Cuts (0, n): the child is a. Cuts (3, 3) are impossible (distinct), cuts (0, 1): a[0] then b's order."""
    a, b = np.array([3, 1, 0, 2]), np.array([2, 0, 3, 1])
    assert order_crossover(a, b, Scripted(choice=[0, 4])).tolist() == [3, 1, 0, 2]
    assert order_crossover(a, b, Scripted(choice=[1, 0])).tolist() == [3, 2, 0, 1]


def test_order_crossover_children_are_permutations():
    """With the real generator every child is a permutation that keeps one contiguous slice of a in place
    and lists the remaining robots in b's order."""
    rng = np.random.default_rng(0)
    for _ in range(200):
        a, b = rng.permutation(7), rng.permutation(7)
        child = order_crossover(a, b, rng)
        assert sorted(child.tolist()) == list(range(7))
        same = np.flatnonzero(child == a)
        kept = [i for i in range(7) if child[i] == a[i]]
        rest = [x for x in child.tolist() if x not in a[same].tolist()]
        assert rest == [x for x in b.tolist() if x in rest] and kept == same.tolist()


def test_swap_mutation_by_hand():
    """Groups of sizes (2, 3, 3) over positions 0-1, 2-4, 5-7. Position 3 is drawn (group 1); the partner is
    drawn among the positions of the other groups, (0, 1, 5, 6, 7); the script picks 7: positions 3 and 7
    swap. The input is not modified."""
    order = np.array([4, 0, 6, 1, 7, 3, 5, 2])
    rng = Scripted(choice=7, integers=3)
    out = swap_mutation(order, (2, 3, 3), rng)
    assert out.tolist() == [4, 0, 6, 2, 7, 3, 5, 1]
    assert order.tolist() == [4, 0, 6, 1, 7, 3, 5, 2]
    assert rng.calls == [("integers", 8), ("choice", [0, 1, 5, 6, 7], None, True)]


def test_swap_mutation_of_one_group_is_a_no_op():
    """A single group has no other group to swap with: the order comes back unchanged, no draw made."""
    rng = Scripted()
    assert swap_mutation(np.array([2, 0, 1]), (3,), rng).tolist() == [2, 0, 1] and rng.calls == []


def test_swap_mutation_always_changes_the_partition():
    """With the real generator: exactly two positions change, in different groups."""
    rng = np.random.default_rng(1)
    group_of = np.repeat([0, 1, 2], [3, 3, 3])
    for _ in range(200):
        order = rng.permutation(9)
        out = swap_mutation(order, (3, 3, 3), rng)
        changed = np.flatnonzero(out != order)
        assert len(changed) == 2 and group_of[changed[0]] != group_of[changed[1]]


def counting(table):
    """An evaluator returning ``table(plan)`` that records every plan it is asked about."""
    asked = []

    def evaluate(plans):
        asked.extend(p.key() for p in plans)
        return np.array([table(p) for p in plans])

    return evaluate, asked


def first_group_sum(plan: Plan) -> float:
    """e_l = sum of the robots moving first: minimal (0 + 1 = 1) for the first group {0, 1}."""
    return float(sum(plan.groups[0]))


def test_genetic_search_evaluates_each_partition_once_and_keeps_the_best_ever():
    """Every distinct partition is evaluated once (the cache), the count returned is the number of
    distinct partitions evaluated, and, the two best plans being carried over each generation (elitism),
    the result is the best of every plan evaluated: with 8 robots in two groups of 4 and e_l = sum of the
    first group, the optimum {0, 1, 2, 3} (e_l 6) is found."""
    evaluate, asked = counting(first_group_sum)
    seeds = [Plan.equal(np.array([7, 6, 5, 4, 3, 2, 1, 0]), 4)]
    known: dict = {}
    plan, e_l, fresh = genetic_search(evaluate, seeds, lambda p: True, np.random.default_rng(3),
                                      GeneticConfig(generations=30, patience=30), known)
    assert len(asked) == len(set(asked)) == fresh == len(known)
    assert e_l == min(known.values()) == first_group_sum(plan)
    assert plan.key()[0] == (0, 1, 2, 3) and e_l == 6.0


def test_genetic_search_reuses_known_scores_and_counts_only_new_ones():
    """Scores already in ``known`` are not asked for again, and the count excludes them."""
    seed = Plan.equal(np.arange(6), 3)
    known = {seed.key(): 0.5}
    evaluate, asked = counting(first_group_sum)
    plan, e_l, fresh = genetic_search(evaluate, [seed], lambda p: True, np.random.default_rng(0), GeneticConfig(), known)
    assert seed.key() not in asked and fresh == len(known) - 1 == len(asked)
    assert (plan.key(), e_l) == (seed.key(), 0.5)  # 0.5 beats every sum of three distinct robots (>= 3)


def test_infeasible_plans_are_never_evaluated():
    """All plans infeasible: nothing is evaluated, no plan is returned, e_l is inf; each infeasible
    partition is recorded once (as inf). Only feasible ones reach the evaluator otherwise."""
    evaluate, asked = counting(first_group_sum)
    known: dict = {}
    plan, e_l, fresh = genetic_search(evaluate, [Plan.equal(np.arange(4), 2)], lambda p: False,
                                      np.random.default_rng(0), GeneticConfig(), known)
    assert (plan, e_l, asked) == (None, np.inf, []) and fresh == len(known) > 0
    assert all(v == np.inf for v in known.values())
    def feasible(p):  # robot 0 may not move first
        return 0 not in p.groups[0]

    plan, e_l, _ = genetic_search(evaluate, [Plan.equal(np.array([1, 2, 0, 3]), 2)], feasible,
                                  np.random.default_rng(0), GeneticConfig())
    assert all(0 not in k[0] for k in asked)
    assert plan.key() == ((1, 2), (0, 3)) and e_l == 3.0  # best feasible: {1, 2} first


def test_genetic_search_stops_after_patience_generations_without_improvement():
    """A constant e_l never improves: the search stops after ``patience`` generations, so the evaluator is
    called for the initial population and then once per generation (each generation of 10 children of
    8 robots in groups of 4 (70 partitions) brings fresh ones): 1 + patience calls, or
    1 + generations when that is smaller."""
    for cfg, calls in ((GeneticConfig(patience=3, generations=8), 4), (GeneticConfig(patience=5, generations=2), 3)):
        batches = []

        def evaluate(plans, batches=batches):
            batches.append(len(plans))
            return np.ones(len(plans))

        genetic_search(evaluate, [Plan.equal(np.arange(8), 4)], lambda p: True, np.random.default_rng(5), cfg)
        assert len(batches) == calls


def test_without_mutation_copies_of_one_plan_breed_only_that_plan():
    """A population of 4 copies of one plan: OX1 of two identical parents is that parent, so without
    mutation (probability 0) no other partition ever appears: exactly one evaluation. With probability 1
    every child is swapped: other partitions appear."""
    seeds = [Plan.equal(np.arange(6), 3)] * 4
    for prob, single in ((0.0, True), (1.0, False)):
        evaluate, asked = counting(first_group_sum)
        genetic_search(evaluate, seeds, lambda p: True, np.random.default_rng(2),
                       GeneticConfig(population=4, elite=1, mutation=prob))
        assert (asked == [seeds[0].key()]) == single


def swapped_pair(plan: Plan, other: Plan) -> bool:
    """Whether ``other`` is ``plan`` with exactly two robots of different groups exchanged."""
    moved = [set(a) ^ set(b) for a, b in zip(plan.key(), other.key(), strict=True)]
    return sum(len(m) for m in moved) == 4 and sum(bool(m) for m in moved) == 2


def test_single_swaps_are_distinct_neighbours_and_all_of_them_when_there_is_room():
    """8 robots in 4 groups of 2 (n_a = 6): 28 pairs, 4 inside a group, so 24 single swaps, each a different
    partition one exchange away; asked for more, all 24 come back; asked for 11, 11 distinct ones."""
    plan = Plan.equal(np.array([3, 1, 4, 0, 7, 5, 2, 6]), 6)
    every = single_swaps(plan, 100, np.random.default_rng(0))
    assert len(every) == len({p.key() for p in every}) == 24 and plan.key() not in {p.key() for p in every}
    assert all(swapped_pair(plan, p) for p in every)
    some = single_swaps(plan, 11, np.random.default_rng(1))
    assert len({p.key() for p in some}) == 11 and {p.key() for p in some} <= {p.key() for p in every}
    assert [p.key() for p in some] == [p.key() for p in single_swaps(plan, 11, np.random.default_rng(1))]  # deterministic


def first_generation(seed: Plan, cfg: GeneticConfig) -> list[Plan]:
    batches = []

    def evaluate(plans):
        batches.append(list(plans))
        return np.ones(len(plans))

    genetic_search(evaluate, [seed], lambda p: True, np.random.default_rng(4), cfg)
    return batches[0]


def test_first_generation_adds_single_swaps_of_the_seed_only_in_a_large_plan_space():
    """2520 plans (8 robots, n_a = 6) are more than population x (generations + 1) = 12 x 9 = 108: the
    first generation is the seed, 11 random plans and 6 distinct single swaps of the seed. 70 plans
    (n_a = 4) are fewer: the seed and 11 random plans only, as before (at most 12 distinct plans)."""
    large = Plan.equal(np.arange(8), 6)
    cfg = GeneticConfig()
    assert n_partitions(large.sizes) == 2520 and not cfg.covers(2520) and cfg.covers(70)
    first = first_generation(large, cfg)
    assert len(first) == 18 and first[0].key() == large.key()
    assert len({p.key() for p in first[12:]}) == 6 and all(swapped_pair(large, p) for p in first[12:])
    small = Plan.equal(np.arange(8), 4)
    assert n_partitions(small.sizes) == 70 and len(first_generation(small, cfg)) <= 12  # distinct plans evaluated


def needle(seed: Plan, target: Plan):
    """e_l 0 at ``target``, 0.5 at ``seed``, 1 everywhere else: nothing leads towards the target."""
    return lambda plans: np.array([0.0 if p.key() == target.key() else 0.5 if p.key() == seed.key() else 1.0 for p in plans])


def test_a_needle_one_swap_from_the_seed_is_found_in_a_large_plan_space():
    """2520 plans (8 robots, n_a = 6) and one good plan, a single swap away from the seed (the heuristic
    plan). With all 24 swaps in the first generation the search finds it for every random seed; with the
    default 6 it is found for 22 of 50 seeds; without swaps (random plans only, the search before this
    rule) for 12 of 50 (by mutating copies of the seed)."""
    seed = Plan.equal(np.arange(8), 6)
    order = seed.order.copy()
    order[0], order[7] = order[7], order[0]
    target = Plan(order, seed.sizes)

    def found(cfg: GeneticConfig, s: int) -> bool:
        plan, e_l, _ = genetic_search(needle(seed, target), [seed], lambda p: True, np.random.default_rng(s), cfg)
        return plan.key() == target.key() and e_l == 0.0

    assert all(found(GeneticConfig(swaps=24), s) for s in range(10))
    assert sum(found(GeneticConfig(), s) for s in range(50)) >= 18
    assert sum(found(GeneticConfig(swaps=0), s) for s in range(50)) <= 15


# ---------------------------------------------------------------------------------------------
# Cramer-Rao prediction (crlb_rank)


def far_apart_estimate(sigma_p: float, sigma_h: float) -> tuple[SwarmEstimate, np.ndarray]:
    """Two robots 10 m apart (never within sensing range), heading 0, each to move 0.2 m along x."""
    ids = np.arange(2)
    poses = np.array([[0.0, 0.0, 0.0], [10.0, 0.0, 0.0]])
    return SwarmEstimate.isotropic(ids, poses, sigma_p, sigma_h), poses[:, :2] + [0.2, 0.0]


def test_crlb_prediction_without_observations_is_dead_reckoning():
    """No observation ever: the bound is the dead-reckoning covariance. The prior has trace s_p^2 in
    position (``isotropic`` splits it over x and y); driving d = 0.2 m straight ahead (no turn) adds
    (0.05 d)^2 along x and (d s_turn)^2 + (d s_heading)^2 across (first order), so each robot ends with
    trace s_p^2 + (0.05 d)^2 + d^2 (s_turn^2 + s_h^2), and e_l = sqrt(pi)/2 sqrt(trace).
    Both plans (either robot first) give that, since each robot moves once and keeps its covariance after."""
    cfg = ModelConfig()
    s_p, s_h, d = 0.01, 0.02, 0.2
    estimate, desired = far_apart_estimate(s_p, s_h)
    trace = s_p**2 + (0.05 * d) ** 2 + d**2 * (cfg.turn_sigma_rad**2 + s_h**2)
    assert MEAN_NORM == pytest.approx(math.sqrt(math.pi) / 2)
    plans = [Plan.equal(np.array([0, 1]), 1), Plan.equal(np.array([1, 0]), 1)]
    np.testing.assert_allclose(predicted_errors(cfg, estimate, desired, plans), math.sqrt(math.pi) / 2 * math.sqrt(trace), rtol=1e-9)


def test_crlb_prediction_of_one_mover_averages_over_robots():
    """Robot 1 is already at its desired position (its step is a zero move): its trace stays s_p^2, robot 0's
    grows as above; e_l is the mean of the two robots' sqrt(pi)/2 sqrt(trace), not the value of the mean trace."""
    cfg = ModelConfig()
    s_p, s_h, d = 0.01, 0.02, 0.2
    estimate, desired = far_apart_estimate(s_p, s_h)
    desired = np.array([[0.2, 0.0], [10.0, 0.0]])  # robot 1 is already there
    plan = Plan.equal(np.array([0, 1]), 1)
    moved = s_p**2 + (0.05 * d) ** 2 + d**2 * (cfg.turn_sigma_rad**2 + s_h**2)
    want = math.sqrt(math.pi) / 2 * (math.sqrt(moved) + s_p) / 2
    assert predicted_errors(cfg, estimate, desired, [plan])[0] == pytest.approx(want, rel=1e-9)


def test_crlb_prediction_uses_the_observations_at_the_expected_poses():
    """Robots 0.3 m apart: after the step they see each other, so the prediction is below dead reckoning
    (far apart, same motion); and an observation that only exists before the motion does not count:
    robots 0.45 m apart moving 0.2 m away from each other end 0.85 m apart, out of range, which predicts
    exactly the far-apart (dead-reckoning) value."""
    cfg = ModelConfig()
    far, far_desired = far_apart_estimate(0.01, 0.02)
    plan = Plan.equal(np.array([0, 1]), 1)
    e_far = predicted_errors(cfg, far, far_desired, [plan])[0]
    near = SwarmEstimate.isotropic(np.arange(2), np.array([[0.0, 0.0, 0.0], [0.3, 0.0, 0.0]]), 0.01, 0.02)
    e_near = predicted_errors(cfg, near, np.array([[0.2, 0.0], [0.5, 0.0]]), [plan])[0]
    assert e_near < 0.9 * e_far
    apart = SwarmEstimate.isotropic(np.arange(2), np.array([[0.0, 0.0, math.pi], [0.45, 0.0, 0.0]]), 0.01, 0.02)
    e_apart = predicted_errors(cfg, apart, np.array([[-0.2, 0.0], [0.65, 0.0]]), [plan])[0]
    assert e_apart == pytest.approx(e_far, rel=1e-9)


# ---------------------------------------------------------------------------------------------
# Monte Carlo e_l (Eq. 8)


def test_monte_carlo_error_of_blind_robots_is_the_rayleigh_mean():
    """Sensing range 1 um (nobody observes anybody: every robot keeps dead reckoning), exact motion (no
    turn or drive noise) and exact headings: each robot's error stays its initial position error, drawn
    isotropic with std s / sqrt(2) per axis (``isotropic`` splits s over x and y). Eq. 8 averages |e| (not
    its square) over robots, so the expected e_l is the Rayleigh mean (s / sqrt(2)) sqrt(pi / 2) =
    sqrt(pi) / 2 s = 0.886 s (an RMS would give s). 1500 samples of 4 robots: standard error
    0.463 s / sqrt(6000) = 0.6 %."""
    cfg = ModelConfig(turn_sigma_rad=0.0, drive_sigma_frac=0.0, sensing_range_m=1e-6)
    s = 0.02
    poses = np.array([[0.0, 0.0, 0.0], [0.3, 0.0, 1.0], [0.0, 0.3, 2.0], [0.3, 0.3, -1.0]])
    estimate = SwarmEstimate.isotropic(np.arange(4), poses, s, 0.0)
    desired = poses[:, :2] + 0.1
    mc = MonteCarlo(cfg, make_localizer("joint", cfg), 1500, seed=3)
    per_sample = mc.localization_errors(estimate, desired, [Plan.equal(np.arange(4), 2)], per_sample=True)
    assert per_sample.shape == (1, 1500)
    assert per_sample.mean() == pytest.approx(s * math.sqrt(math.pi) / 2, rel=0.03)
    assert mc.localization_errors(estimate, desired, [Plan.equal(np.arange(4), 2)])[0] == pytest.approx(per_sample.mean(), rel=1e-12)
    # The same errors drawn from a joint covariance (block-diagonal here: the same distribution).
    joint = np.zeros((12, 12))
    for k in range(4):
        joint[3 * k : 3 * k + 3, 3 * k : 3 * k + 3] = estimate.cov[k]
    carried = SwarmEstimate.from_joint(estimate.ids, poses, joint)
    e_joint = mc.localization_errors(carried, desired, [Plan.equal(np.arange(4), 2)], per_sample=True)
    assert e_joint.shape == (1, 1500)
    assert e_joint.mean() == pytest.approx(s * math.sqrt(math.pi) / 2, rel=0.03)


def test_monte_carlo_error_of_an_exact_swarm_is_zero():
    """Exact initial estimate, motion and sensing: every localizer recovers the truth, e_l = 0 for every plan."""
    cfg = ModelConfig(turn_sigma_rad=0.0, drive_sigma_frac=0.0, range_sigma_m=0.0, bearing_sigma_rad=0.0)
    poses = np.array([[0.0, 0.0, 0.0], [0.25, 0.0, 1.0], [0.0, 0.25, 2.0], [0.25, 0.25, -1.0]])
    estimate = SwarmEstimate.isotropic(np.arange(4), poses, 0.0, 0.0)
    plans = [Plan.equal(np.arange(4), 2), Plan.equal(np.array([3, 1, 2, 0]), 2)]
    for method in BUILTIN_LOCALIZERS:
        e_l = MonteCarlo(cfg, make_localizer(method, cfg), 4, seed=0).localization_errors(estimate, poses[:, :2] + [0.05, 0.0], plans)
        np.testing.assert_allclose(e_l, 0.0, atol=1e-6)


def test_connectivity_is_checked_after_every_step():
    """Robots at x = 0, 0.4, 0.8 m (sensing 0.5 m), desired x = 0.6, 1.0, 1.2 (connected). Moving robot 2
    first leaves 0, 0.4, 1.2: a 0.8 m gap, so that plan is refused although its end is connected. Moving
    0, then 1, then 2 passes through (0.6, 0.4, 0.8) and (0.6, 1.0, 0.8): connected after every step."""
    current = np.array([[0.0, 0.0], [0.4, 0.0], [0.8, 0.0]])
    desired = np.array([[0.6, 0.0], [1.0, 0.0], [1.2, 0.0]])
    assert not plan_keeps_connectivity(Plan(np.array([2, 0, 1]), (1, 1, 1)), current, desired, 0.5)
    assert plan_keeps_connectivity(Plan(np.array([0, 1, 2]), (1, 1, 1)), current, desired, 0.5)
    assert not plan_keeps_connectivity(Plan(np.array([0, 1, 2]), (1, 1, 1)), current, desired, 0.39)  # 0.4 m gaps
    assert current.tolist() == [[0.0, 0.0], [0.4, 0.0], [0.8, 0.0]]  # not modified


def test_crlb_prediction_counts_pairs_exactly_at_sensing_range():
    """Robots 0 and 1 start 1 m apart; robot 0 moves to 0.125 (0.875 m apart: no observation), then robot 1
    to 0.625: exactly 0.5 m, the sensing range (inclusive), so from then on they observe each other and the
    prediction is below that of the same moves 10 m further apart (never observed); robot 2 is far away."""
    cfg = ModelConfig()
    plan = Plan.equal(np.array([0, 1, 2]), 2)
    start = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [20.0, 0.0, 0.0]])
    desired = np.array([[0.125, 0.0], [0.625, 0.0], [20.125, 0.0]])  # robots 0 and 1 end 0.5 m apart
    near = predicted_errors(cfg, SwarmEstimate.isotropic(np.arange(3), start, 0.01, 0.02), desired, [plan])[0]
    apart = start.copy()
    apart[1, 0] += 10.0
    desired_apart = desired.copy()
    desired_apart[1, 0] += 10.0
    far = predicted_errors(cfg, SwarmEstimate.isotropic(np.arange(3), apart, 0.01, 0.02), desired_apart, [plan])[0]
    assert near < 0.95 * far


def test_race_keeps_the_best_whatever_its_position():
    """Four plans whose e_l is known exactly (no noise): the best is the last one listed; the race returns it after one
    round (with no spread every other plan is clearly worse)."""
    from coordinator.selection.racing import race

    plans = [Plan.equal(np.roll(np.arange(6), k), 3) for k in range(4)]
    truth = {p.key(): 1.0 - 0.1 * k for k, p in enumerate(plans)}
    winner, spent, _, _, _ = race(plans, lambda ps, samples, seed: np.array([[truth[p.key()]] * samples for p in ps]), 8,
                         np.random.default_rng(0))
    assert winner.key() == plans[3].key() and spent == 4


def test_final_check_is_a_one_sided_paired_test():
    """Per-sample differences champion - seed = (-0.5, -0.2, 0.1): mean -0.2, sample std (ddof 1) 0.3,
    standard error 0.3 / sqrt(3) = 0.173; -0.2 + 0.173 < 0: the champion is kept. With a single sample
    the standard error is taken as 0: a better champion is kept."""
    from coordinator.selection.racing import final_check

    champion, seed = Plan.equal(np.arange(4), 2), Plan.equal(np.array([2, 3, 0, 1]), 2)
    seed_e = np.array([1.0, 1.0, 1.0])

    def evaluate(plans, samples, fresh):
        rows = {champion.key(): seed_e[:samples] + np.array([-0.5, -0.2, 0.1])[:samples], seed.key(): seed_e[:samples]}
        return np.stack([rows[p.key()] for p in plans])

    kept, e_kept, e_seed, looked = final_check(champion, seed, evaluate, 3, 0)
    assert looked == 1
    assert kept.key() == champion.key() and e_kept == pytest.approx(0.8) and e_seed == pytest.approx(1.0)
    kept, e_kept, _, _ = final_check(champion, seed, evaluate, 1, 0)
    assert kept.key() == champion.key() and e_kept == pytest.approx(0.5)
    # Two samples, differences (-0.5, -0.2): mean -0.35, std 0.212, standard error 0.15: champion kept.
    assert final_check(champion, seed, evaluate, 2, 0)[0].key() == champion.key()


def test_final_check_with_two_samples_uses_their_spread():
    """Differences (-0.3, 0.1): mean -0.1, sample std 0.283, standard error 0.2: -0.1 + 0.2 > 0, the seed
    is kept (a better mean alone is not enough)."""
    from coordinator.selection.racing import final_check

    champion, seed = Plan.equal(np.arange(4), 2), Plan.equal(np.array([2, 3, 0, 1]), 2)

    def evaluate(plans, samples, fresh):
        rows = {champion.key(): np.array([0.7, 1.1]), seed.key(): np.array([1.0, 1.0])}
        return np.stack([rows[p.key()] for p in plans])

    assert final_check(champion, seed, evaluate, 2, 0) == (seed, 1.0, 1.0, 1)


@pytest.mark.parametrize(
    ("field", "value", "ok"),
    [("final_samples", 0, False), ("final_samples", 1, True), ("contenders", 0, False), ("contenders", 1, True),
     ("prune_gain", -0.01, False), ("prune_gain", 0.0, True), ("prune_gain", 1.0, True), ("prune_gain", 1.01, False),
     ("samples", 0, False), ("samples", 1, True), ("method", "grid", False)],
)
def test_selection_config_bounds(field, value, ok):
    """Each budget is checked on its own, inclusive bounds accepted: final samples and contenders >= 1,
    prune gain in [0, 1], samples >= 1, a known method."""
    from dataclasses import replace

    from coordinator.selection.selector import SelectionConfig
    from runtime.errors import SwarmInputError

    if ok:
        assert getattr(replace(SelectionConfig(), **{field: value}), field) == value
    else:
        with pytest.raises(SwarmInputError):
            replace(SelectionConfig(), **{field: value})


# ---------------------------------------------------------------------------------------------
# Budgets in evaluations: screening by prediction, sequential final check


def test_screened_search_keeps_the_seed_when_nothing_beats_it():
    """The prediction says every other plan is better (0.1 against 0.5), Monte Carlo says the seed is best:
    the search returns the seed with its Monte Carlo e_l, having evaluated at most seeds + 2 x screened (the seed
    with the first generation's best predicted, in one pass) + screened per generation plans by Monte Carlo."""
    seed = Plan.equal(np.arange(8), 4)
    evaluated: list[int] = []
    first: list[PlanKey] = []

    def evaluate(plans):
        evaluated.append(len(plans))
        first.extend(p.key() for p in plans if len(evaluated) == 1)
        return np.array([0.5 if p.key() == seed.key() else 1.0 for p in plans])

    def predict(plans):
        return np.array([0.5 if p.key() == seed.key() else 0.1 for p in plans])

    cfg = GeneticConfig(screened=2)
    plan, e_l, fresh = genetic_search(evaluate, [seed], lambda p: True, np.random.default_rng(1), cfg, {}, predict)
    assert plan.key() == seed.key() and e_l == 0.5
    assert first[0] == seed.key() and evaluated[0] == 1 + 2 * cfg.screened and max(evaluated[1:], default=0) <= cfg.screened
    assert fresh == sum(evaluated) <= 1 + cfg.screened * (cfg.generations + 2)


def test_screened_search_evaluates_the_best_predicted_and_finds_the_needle():
    """With a prediction that points at the needle (one swap from the seed, 2520 plans), the screened search
    finds it as often as the unscreened one (22 of 50 random seeds, test above: >= 18), spending Monte Carlo
    only on the seed and the best-predicted plans (at most 1 + 2 x 10 = 21 instead of a whole population per generation)."""
    seed = Plan.equal(np.arange(8), 6)
    order = seed.order.copy()
    order[0], order[7] = order[7], order[0]
    target = Plan(order, seed.sizes)
    e_of = needle(seed, target)
    found = 0
    for s in range(50):
        known: dict[tuple, float] = {}
        plan, e_l, fresh = genetic_search(e_of, [seed], lambda p: True, np.random.default_rng(s), GeneticConfig(), known,
                                          lambda plans: e_of(plans) + 0.01)
        found += plan.key() == target.key() and e_l == 0.0
        assert fresh == len(known) <= 1 + GeneticConfig().screened * (GeneticConfig().generations + 2)
    assert found >= 18


def test_sequential_final_check_never_stops_on_an_undecided_difference():
    """4 looks of 8 + 8 + 16 + 32 = 64 samples. A champion better by 0.1 with per-sample spread 1 is undecided
    at every interim look (|mean| < 2 standard errors): every block is evaluated and the last look decides by
    one standard error. A champion better (or worse) by 1 with spread 0.1 is decided at the first look."""
    from coordinator.selection.racing import EARLY_MARGIN, final_check, fresh_blocks

    champion, seed = Plan.equal(np.arange(4), 2), Plan.equal(np.array([2, 3, 0, 1]), 2)
    blocks = fresh_blocks(64, 7, 4)
    assert [m for m, _ in blocks] == [8, 8, 16, 32] and blocks[0][1] == 7 and len({s for _, s in blocks}) == 4
    asked: list[tuple[int, int]] = []

    def evaluator(shift: float, spread: float):
        def evaluate(plans, samples, fresh):
            asked.append((samples, fresh))
            wobble = spread * np.where(np.arange(samples) % 2 == 0, 1.0, -1.0)  # mean 0, sample std ~ spread
            rows = {seed.key(): np.ones(samples), champion.key(): 1.0 + shift + wobble}
            return np.stack([rows[p.key()] for p in plans])
        return evaluate

    kept, e_kept, e_seed, looked = final_check(champion, seed, evaluator(-0.1, 1.0), 64, 7, looks=4)
    assert asked == blocks and looked == 4  # never stopped: 0.1 < EARLY_MARGIN x 1 / sqrt(m) at m = 8, 16, 32
    assert EARLY_MARGIN / math.sqrt(32) > 0.1 and kept.key() == seed.key() and e_kept == e_seed == 1.0  # 0.1 < 1 / sqrt(64) too
    asked.clear()
    kept, e_kept, _, looked = final_check(champion, seed, evaluator(-1.0, 0.1), 64, 7, looks=4)
    assert looked == 1 and asked == blocks[:1] and kept.key() == champion.key() and e_kept == pytest.approx(0.0)
    asked.clear()
    kept, _, _, looked = final_check(champion, seed, evaluator(1.0, 0.1), 64, 7, looks=4)
    assert looked == 1 and kept.key() == seed.key()
