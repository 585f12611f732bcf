"""Anchor selection: Monte Carlo with common random numbers, genetic search vs exhaustive, constraints."""

from __future__ import annotations

import math

import numpy as np
import pytest

from coordinator.localization import make_localizer
from coordinator.plan import Plan, enumerate_plans, feasible_anchor_counts, n_solutions
from coordinator.selection.genetic import GeneticConfig, genetic_search
from coordinator.selection.heuristic import heuristic_plan
from coordinator.selection.monte_carlo import MonteCarlo, plan_keeps_connectivity
from coordinator.selection.selector import AnchorSelector, NoFeasiblePlanError, SelectionConfig, samples_for, search_samples
from runtime.models.config import ModelConfig
from runtime.models.state import SwarmEstimate
from runtime.models.trajectory import random_trajectory


def step_problem(n: int, seed: int) -> tuple[SwarmEstimate, np.ndarray]:
    traj = random_trajectory(n, 1, np.random.default_rng(seed))
    return SwarmEstimate.isotropic(traj.ids, traj.initial_poses, 0.01, math.radians(2)), traj.configurations[0]


def test_batch_evaluation_uses_common_random_numbers():
    estimate, desired = step_problem(6, 1)
    mc = MonteCarlo(POINTS, make_localizer("paper", POINTS), 6, seed=11)
    plans = enumerate_plans(6, 3)[:5]
    together = mc.localization_errors(estimate, desired, plans)
    alone = np.array([mc.localization_errors(estimate, desired, [p])[0] for p in plans])
    np.testing.assert_allclose(together, alone, rtol=1e-9)
    assert len(set(np.round(together, 12))) > 1  # plans do differ


@pytest.mark.parametrize("n_a,seed", [(3, 0), (4, 1), (4, 2)])
def test_genetic_search_is_within_5_percent_of_exhaustive_optimum(n_a, seed):
    estimate, desired = step_problem(6, seed)
    mc = MonteCarlo(POINTS, make_localizer("paper", POINTS), 8, seed=seed)
    plans = [p for p in enumerate_plans(6, n_a) if plan_keeps_connectivity(p, estimate.positions, desired, 0.5)]
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
    a = AnchorSelector(POINTS, make_localizer("paper", POINTS), config, seed=5).select(estimate, desired)
    b = AnchorSelector(POINTS, make_localizer("paper", POINTS), config, seed=5).select(estimate, desired)
    assert a.plan.key() == b.plan.key()
    assert [s.e_l for s in a.scores] == [s.e_l for s in b.scores]
    assert [s.n_anchors for s in a.scores] == feasible_anchor_counts(6)
    assert a.scores[0].p_l == 1.0 and a.scores[0].p_v == 1.0  # n_a = 0 defines e_l,max and v_max


def test_single_count_selection_scores_follow_eq_1_to_3():
    """One anchor count: its score follows Eq. 1-3 exactly (n_r = 6, n_a = 3: n_s = 2, P_v = 1/2;
    P_s = 0.5 x 1/2 - 0.5 x e_l / e_l(0)), and the plan chosen partitions the robots into two groups of 3."""
    estimate, desired = step_problem(6, 3)
    config = SelectionConfig(samples=4, anchor_counts=(3,))
    selection = AnchorSelector(POINTS, make_localizer("paper", POINTS), config, seed=5).select(estimate, desired)
    assert [s.n_anchors for s in selection.scores] == [3] and selection.plan.sizes == (3, 3)
    (score,) = selection.scores
    assert score.p_v == 0.5 and score.p_s == pytest.approx(0.25 - 0.5 * score.p_l, abs=1e-15) and score.p_l > 0


def test_weights_move_the_choice_towards_speed_or_accuracy():
    estimate, desired = step_problem(6, 4)
    budget = dict(samples=4, genetic=GeneticConfig(population=6, generations=2))
    fast = AnchorSelector(POINTS, make_localizer("paper", POINTS), SelectionConfig(w_v=1.0, w_l=0.0, **budget),
                          seed=1).select(estimate, desired)
    careful = AnchorSelector(POINTS, make_localizer("paper", POINTS), SelectionConfig(w_v=0.0, w_l=1.0, **budget),
                             seed=1).select(estimate, desired)
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
        AnchorSelector(POINTS, make_localizer("paper", POINTS), SelectionConfig(samples=2), seed=0).select(estimate, desired)


# ------------------------------------------------------------------ the search's guarantees

from coordinator.selection.crlb_rank import predicted_errors  # noqa: E402
from coordinator.selection.racing import best_distinct, clearly_worse, final_check, fresh_blocks, race  # noqa: E402

POINTS = ModelConfig(robot_radius_m=0.0)  # the paper's point robots: these tests pin its selection and execution maths (bodies: test_bodies.py)

NOISY_JOINT = ModelConfig(turn_sigma_rad=math.radians(9), drive_sigma_frac=0.15, robot_radius_m=0.0)  # motion noise x 3: anchors pay (point robots)


@pytest.mark.parametrize("localizer,seed", [("paper", 0), ("joint", 1), ("joint", 2)])
def test_search_never_returns_a_plan_worse_than_its_seed_on_the_fresh_set(localizer, seed):
    estimate, desired = step_problem(8, seed)
    sel = SelectionConfig(anchor_counts=(4, 6), w_v=0.0, w_l=1.0, genetic_gate="on")  # accuracy only: the count(s) that could win are searched
    result = AnchorSelector(NOISY_JOINT, make_localizer(localizer, NOISY_JOINT), sel, seed=seed).select(estimate, desired)
    assert result.fresh_seed is not None
    blocks = fresh_blocks(samples_for(sel.final_samples, 8), result.fresh_seed, sel.final_looks)
    assert any(entry.searched for entry in result.scores)
    for entry in result.scores:
        assert entry.plan is not None and entry.e_l <= entry.seed_e_l
        if not entry.searched:  # pruned (could not win): its heuristic plan, scored at screening
            assert entry.plan.key() == heuristic_plan(estimate.positions, desired, entry.n_anchors).key()
            continue
        seed_plan = heuristic_plan(estimate.positions, desired, entry.n_anchors)
        each = np.concatenate([MonteCarlo(NOISY_JOINT, make_localizer(localizer, NOISY_JOINT), m, s, sel.mc_start).localization_errors(
            estimate, desired, [entry.plan, seed_plan], per_sample=True) for m, s in blocks], axis=1)
        seen = np.cumsum([m for m, _ in blocks])  # the samples each look of the sequential final check has seen
        looks = [j for j, m in enumerate(seen) if entry.e_l == pytest.approx(each[0, :m].mean(), rel=1e-12)]
        if entry.plan.key() == seed_plan.key() and not looks:  # the race kept the seed: no final check
            screen_seed = int(np.random.default_rng([seed, 1]).integers(2**63))
            screen = MonteCarlo(NOISY_JOINT, make_localizer(localizer, NOISY_JOINT), samples_for(sel.samples, 8), screen_seed, sel.mc_start)
            assert entry.e_l == entry.seed_e_l == pytest.approx(screen.localization_errors(estimate, desired, [seed_plan])[0], rel=1e-12)
            continue
        assert looks, "the reported e_l is the fresh set's (over the blocks the final check saw), not the search's"
        assert entry.seed_e_l == pytest.approx(each[1, : seen[looks[0]]].mean(), rel=1e-12)


def test_final_check_keeps_the_seed_unless_the_champion_is_better_on_fresh_samples():
    a, b = Plan.equal(np.arange(4), 2), Plan.equal(np.array([2, 3, 0, 1]), 2)

    def evaluate(plans, samples, seed):  # per sample; b is better on even seeds, worse on odd ones; seed 4: better only by noise
        wobble = np.where(np.arange(samples) % 2 == 0, 0.3, -0.3)
        rows = {a.key(): np.ones(samples), b.key(): np.full(samples, 0.9 if seed % 2 == 0 else 1.1) + (wobble if seed == 4 else 0.0)}
        return np.stack([rows[p.key()] for p in plans])

    assert final_check(b, a, evaluate, 8, 2)[:2] == (b, pytest.approx(0.9))
    assert final_check(b, a, evaluate, 8, 3)[:2] == (a, 1.0)
    assert final_check(b, a, evaluate, 8, 4)[:2] == (a, 1.0)  # 0.1 better on average, but within one standard error
    assert final_check(a, a, evaluate, 8, 3) == (a, 1.0, 1.0, 1)


def race_case(gap: float, common: float = 0.3, own: float = 0.1, count: int = 4):
    """``count`` plans 1 + ``gap`` k apart; per sample a draw shared by the plans (common random numbers, sd ``common``)
    plus each plan's own (sd ``own``); the evaluator records (plans, samples) of each call."""
    plans = enumerate_plans(6, 3)[:count]
    truth = np.array([1.0 + gap * k for k in range(count)])
    keys = [p.key() for p in plans]
    seen: list[tuple[int, int]] = []

    def evaluate(ps, samples, seed):
        seen.append((len(ps), samples))
        draws = np.random.default_rng(seed)
        shared = draws.normal(0, common, samples)
        rows = [keys.index(p.key()) for p in ps]
        return truth[rows, None] + shared + draws.normal(0, own, (len(ps), samples))

    return plans, evaluate, seen


def test_race_spends_more_samples_on_contenders_and_finds_the_best():
    plans, evaluate, seen = race_case(gap=0.003)  # within the noise: plain halving, every round
    winner, spent, stopped, _, _ = race(plans, evaluate, 64, np.random.default_rng(0))
    assert winner.key() == plans[0].key()
    assert seen == [(4, 64), (2, 128)] and spent == 6 and not stopped


@pytest.mark.parametrize("seed", range(5))
def test_race_drops_clearly_worse_contenders_early_and_never_the_clear_best(seed):
    """Eight plans 5 % apart, each sample's spread (0.3 shared, 0.02 own) far above the gap: common random numbers
    decide them in the first round, which eliminates all but the best (plain halving would spend 8 + 4 + 2)."""
    plans, evaluate, seen = race_case(gap=0.05, own=0.02, count=8)
    winner, spent, stopped, _, _ = race(plans, evaluate, 16, np.random.default_rng(seed))
    assert winner.key() == plans[0].key() and seen == [(8, 16)] and spent == 8 and not stopped


def test_a_race_whose_leader_cannot_win_stops_and_says_so():
    plans, evaluate, seen = race_case(gap=0.003, count=8)
    told: list[tuple[int, int]] = []

    def hopeless(e_l, blocks):  # judged on the leader's e_l over every block seen
        told.append((len(e_l), sum(b[0] for b in blocks)))
        return len(blocks) == 2

    result = race(plans, evaluate, 16, np.random.default_rng(0), hopeless=hopeless)
    assert result.stopped and seen == [(8, 16), (4, 32)] and told == [(16, 16), (48, 48)] and result.spent == 12
    assert len(result.e_l) == 48 and [b[0] for b in result.blocks] == [16, 32]


@pytest.mark.parametrize("seed", range(3))
def test_a_round_seen_in_halves_drops_the_clearly_worse_after_the_first(seed):
    """Eight plans 5 % apart, decided by common random numbers within 16 samples: with ``look`` = 16 the first round
    (32 samples) stops after its first half; a race within the noise sees every round in full, in two halves each."""
    plans, evaluate, seen = race_case(gap=0.05, own=0.02, count=8)
    result = race(plans, evaluate, 32, np.random.default_rng(seed), look=16)
    assert result.winner.key() == plans[0].key() and seen == [(8, 16)] and result.spent == 8
    plans, evaluate, seen = race_case(gap=0.003)
    result = race(plans, evaluate, 32, np.random.default_rng(seed), look=16)
    assert [m for _, m in seen] == [16, 16, 32, 32][: len(seen)] and seen[0][0] == 4 and len(result.e_l) == sum(m for _, m in seen)
    assert len({b[1] for b in result.blocks}) == len(result.blocks)  # each half its own samples


def test_a_final_check_stops_keeping_the_seed_once_neither_plan_can_win():
    a, b = Plan.equal(np.arange(4), 2), Plan.equal(np.array([2, 3, 0, 1]), 2)

    def evaluate(plans, samples, seed):  # b 0.2 % better than a, within the noise of every look
        noise = np.random.default_rng(seed).normal(0, 0.2, samples)
        return np.stack([1.0 + noise + (0.0 if p.key() == a.key() else -0.002 + 0.3 * noise[::-1]) for p in plans])

    told: list[tuple[float, int]] = []

    def hopeless(e_l, looked):
        told.append((float(e_l.mean()), looked))
        return looked == 2

    kept, _, _, looked = final_check(b, a, evaluate, 64, 5, looks=4, hopeless=hopeless)
    assert kept.key() == a.key() and looked == 2 and [k for _, k in told] == [1, 2]
    assert final_check(b, a, evaluate, 64, 5, looks=4)[3] == 4  # undecided without it: every look


def test_a_contender_is_clearly_worse_only_beyond_the_margin():
    leader = np.array([1.0, 2.0, 3.0, 4.0])
    assert clearly_worse(leader + np.array([0.3, 0.1, 0.2, 0.2]), leader, 2.0)  # mean 0.2, standard error 0.041
    assert not clearly_worse(leader + np.array([0.5, -0.3, 0.4, 0.2]), leader, 2.0)  # mean 0.2, standard error 0.18
    assert not clearly_worse(leader[:1] + 1.0, leader[:1], 2.0)  # one sample: no spread, never decided


def test_best_distinct_ranks_a_cache_by_e_l():
    plans = enumerate_plans(6, 3)[:4]
    truth = {p.key(): 1.0 + 0.05 * k for k, p in enumerate(plans)} | {plans[0].key(): np.inf}
    assert [p.key() for p in best_distinct(truth, 2)] == [plans[1].key(), plans[2].key()]


@pytest.mark.parametrize("method", ["mc", "crlb"])
def test_selection_is_deterministic_for_a_seed(method):
    estimate, desired = step_problem(8, 5)
    sel = SelectionConfig(method=method)
    a, b = (AnchorSelector(NOISY_JOINT, make_localizer("joint", NOISY_JOINT), sel, seed=9).select(estimate, desired) for _ in range(2))
    assert a.plan.key() == b.plan.key()
    assert [(s.n_anchors, s.e_l, s.seed_e_l, s.searched) for s in a.scores] == [(s.n_anchors, s.e_l, s.seed_e_l, s.searched) for s in b.scores]
    assert (a.evaluations, a.fresh_seed) == (b.evaluations, b.fresh_seed)  # the budget is counted in evaluations, not time


@pytest.mark.parametrize("n_a,seed", [(3, 0), (4, 1), (4, 3)])
def test_crlb_search_is_near_exhaustive_enumeration_on_small_swarms(n_a, seed):
    estimate, desired = step_problem(6, seed)
    plans = [p for p in enumerate_plans(6, n_a) if plan_keeps_connectivity(p, estimate.positions, desired, 0.5)]
    predicted = predicted_errors(NOISY_JOINT, estimate, desired, plans)
    chosen = AnchorSelector(NOISY_JOINT, make_localizer("joint", NOISY_JOINT), SelectionConfig(method="crlb", anchor_counts=(n_a,)),
                            seed=seed).select(estimate, desired)
    assert chosen.scores[0].e_l in predicted  # the prediction of one of the feasible plans, not an estimate
    assert predicted.min() <= chosen.scores[0].e_l <= 1.02 * predicted.min()  # the genetic search gets within 2 %


def test_mc_search_is_near_the_exhaustive_optimum_on_independent_samples():
    estimate, desired = step_problem(6, 2)
    plans = [p for p in enumerate_plans(6, 3) if plan_keeps_connectivity(p, estimate.positions, desired, 0.5)]
    chosen = AnchorSelector(NOISY_JOINT, make_localizer("joint", NOISY_JOINT), SelectionConfig(anchor_counts=(3,), genetic_gate="on"),
                            seed=4).select(estimate, desired).plan
    pick, judge = (MonteCarlo(NOISY_JOINT, make_localizer("joint", NOISY_JOINT), 256, seed=s) for s in (999, 12345))  # independent sets
    optimum = plans[int(np.argmin(pick.localization_errors(estimate, desired, plans)))]
    e_chosen, e_optimum = judge.localization_errors(estimate, desired, [chosen, optimum])
    print(f"chosen / optimum on independent samples: {e_chosen / e_optimum:.4f}")
    assert e_chosen <= 1.02 * e_optimum


def test_counts_that_cannot_win_are_not_searched():
    estimate, desired = step_problem(8, 6)
    speed_only = AnchorSelector(POINTS, make_localizer("paper", POINTS), SelectionConfig(w_v=1.0, w_l=0.0),
                                seed=1).select(estimate, desired)
    assert not any(s.searched for s in speed_only.scores)  # P_v alone decides: n_a = 0, screening only
    assert speed_only.evaluations == len(feasible_anchor_counts(8)) and speed_only.fresh_seed is None
    accuracy_only = AnchorSelector(POINTS, make_localizer("paper", POINTS), SelectionConfig(w_v=0.0, w_l=1.0),
                                   seed=1).select(estimate, desired)
    assert all(s.searched for s in accuracy_only.scores if s.n_anchors > 0)


def test_search_samples_grow_with_the_log_of_the_plan_space():
    """S x ln(plans) / ln(252), between 1x and 2x: n_r = 8 (S = 20): n_a = 4 (70 plans) 20, n_a = 6 (2520) 29,
    n_a = 7 (40320) 39; n_r = 10 (S = 16): n_a = 5 (252) 16, n_a = 8 (113400) and 9 (10!) capped at 32."""
    assert [search_samples(20, n_solutions(8, k)) for k in (4, 6, 7)] == [20, 29, 39]
    assert [search_samples(16, n_solutions(10, k)) for k in (5, 8, 9)] == [16, 32, 32]


def test_a_large_count_is_searched_and_raced_on_more_samples(monkeypatch):
    """n_r = 8, n_a = 6 (2520 plans), S = samples_for(4, 8) = 5: screening on 5 samples (e_l(0) and the count's
    heuristic plan in one pass), the genetic search and
    the race on search_samples(5, 2520) = 8 (race rounds 8, 16, 32), the final check on samples_for(256, 8) = 320
    (no screening by prediction, 8 contenders, one look: the budget that compares many plans by Monte Carlo)."""
    import coordinator.selection.selector as selector

    sizes = []

    class Recording(MonteCarlo):
        def localization_errors(self, *args, **kwargs):
            sizes.append(self.samples)
            return super().localization_errors(*args, **kwargs)

    monkeypatch.setattr(selector, "MonteCarlo", Recording)
    estimate, desired = step_problem(8, 2)
    config = SelectionConfig(samples=4, anchor_counts=(6,), genetic=GeneticConfig(generations=2, screened=0), contenders=8, final_looks=1)
    selection = AnchorSelector(POINTS, make_localizer("paper", POINTS), config, seed=1).select(estimate, desired)
    assert selection.scores[0].searched and samples_for(4, 8) == 5 and search_samples(5, 2520) == 8
    assert set(sizes) == {5, 8, 16, 32, 320} and sizes[:2] == [5, 8]


def test_only_the_joint_localizers_search_is_screened_by_the_prediction():
    """The Cramer-Rao prediction ranks plans as the joint localizer reaches them, not as the paper's (Eq. 23) does."""
    joint, paper = (make_localizer(name, POINTS) for name in ("joint", "paper"))
    assert AnchorSelector(POINTS, joint, SelectionConfig(), seed=0).screens()
    assert not AnchorSelector(POINTS, paper, SelectionConfig(), seed=0).screens()
    assert not AnchorSelector(POINTS, joint, SelectionConfig(method="crlb"), seed=0).screens()  # the prediction is the fitness
    assert not AnchorSelector(POINTS, joint, SelectionConfig(genetic=GeneticConfig(screened=0)), seed=0).screens()
