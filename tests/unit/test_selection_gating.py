"""Where the genetic search runs, the outer-loop bound, the repair of crowded seeds and determinism."""

import math
from dataclasses import replace

import numpy as np
import pytest

from coordinator.localization import make_localizer
from coordinator.plan import Plan, enumerate_plans, speed_performance
from coordinator.selection.clear_pairs import PairTable
from coordinator.selection.heuristic import heuristic_plan
from coordinator.selection.monte_carlo import MonteCarlo, plan_keeps_connectivity
from coordinator.selection.repair import conflicts, repair
from coordinator.selection.selector import AnchorSelector, SelectionConfig, genetic_pays, samples_for
from inchworm.bench.options import SelectBenchOptions
from inchworm.bench.select import bench_select
from inchworm.options import RunOptions
from runtime.errors import SwarmInputError
from runtime.models.bodies import BodyCheck
from runtime.models.config import ModelConfig
from runtime.models.state import SwarmEstimate
from runtime.models.trajectory import body_spacing, random_trajectory

POINTS = ModelConfig(robot_radius_m=0.0)
BODIES = ModelConfig()  # radius 0.011 m


def step_problem(n: int, seed: int, cfg: ModelConfig = POINTS) -> tuple[SwarmEstimate, np.ndarray]:
    """The random step ``swarm bench select`` draws for size ``n`` and repeat ``seed``."""
    traj = random_trajectory(n, 1, np.random.default_rng([0, n, seed]), sensing_range=cfg.sensing_range_m, **body_spacing(cfg))
    return SwarmEstimate.isotropic(traj.ids, traj.initial_poses, 0.01, math.radians(2)), traj.configurations[0]


def test_the_gate_follows_the_measurement_and_can_be_forced():
    assert all(genetic_pays("paper", 10, n_a, cfg) for n_a in (5, 8, 9) for cfg in (POINTS, BODIES))
    assert genetic_pays("paper", 8, 4, BODIES)  # n_r = 8 takes the row of 10
    assert not genetic_pays("paper", 30, 15, BODIES)  # with bodies no heuristic plan of 30 robots was ever clear: nothing to beat
    assert not genetic_pays("paper", 30, 15, POINTS) and not genetic_pays("paper", 100, 50, POINTS)  # it paid there, too slowly
    assert not genetic_pays("joint", 10, 5, BODIES) and genetic_pays("joint", 10, 8, BODIES) and genetic_pays("joint", 10, 9, POINTS)
    assert not genetic_pays("joint", 10, 8, POINTS) and not genetic_pays("my-plugin", 10, 9, POINTS)
    joint = make_localizer("joint", POINTS)
    assert not AnchorSelector(POINTS, joint, SelectionConfig(), 0).genetic_runs(10, 5)
    assert AnchorSelector(POINTS, joint, SelectionConfig(genetic_gate="on"), 0).genetic_runs(10, 5)
    assert AnchorSelector(POINTS, joint, SelectionConfig(method="crlb"), 0).genetic_runs(10, 5)  # no samples to spare
    assert not AnchorSelector(POINTS, make_localizer("paper", POINTS), SelectionConfig(genetic_gate="off"), 0).genetic_runs(10, 5)
    with pytest.raises(SwarmInputError, match="genetic search must be one of auto, on, off"):
        SelectionConfig(genetic_gate="sometimes")


def test_gated_off_counts_keep_their_seed_and_spend_no_search_samples():
    estimate, desired = step_problem(8, 1)
    loc = make_localizer("paper", POINTS)
    accuracy = SelectionConfig(w_v=0.0, w_l=1.0)  # every count with anchors could win: all searched
    off = AnchorSelector(POINTS, loc, replace(accuracy, genetic_gate="off"), seed=3).select(estimate, desired)
    on = AnchorSelector(POINTS, loc, replace(accuracy, genetic_gate="on"), seed=3).select(estimate, desired)
    searched = [s for s in off.scores if s.searched]
    assert searched and not any(s.genetic for s in off.scores) and off.fresh_seed is None
    assert all(s.plan is not None and s.plan.key() == s.seed.key() and s.e_l == s.seed_e_l for s in searched)
    assert off.evaluations == len(off.scores)  # e_l(0) and one plan per count (no crowded seed with point robots)
    assert all(s.genetic for s in on.scores if s.searched) and on.evaluations > 10 * off.evaluations


@pytest.mark.parametrize("w_v,seed", [(0.5, 2), (0.6, 5), (0.4, 1)])
def test_the_outer_loop_bound_never_discards_a_count_that_would_win_on_the_same_samples(w_v, seed):
    """Every count the bound discards: even its best plan (all plans enumerated, on the screening samples)
    has a lower P_s than the best screened count (here the best plans are 2-18 % below their heuristic plan's e_l)."""
    n = 6
    estimate, desired = step_problem(n, seed)
    loc = make_localizer("paper", POINTS)
    config = SelectionConfig(w_v=w_v, w_l=1.0 - w_v, genetic_gate="off")
    result = AnchorSelector(POINTS, loc, config, seed=seed).select(estimate, desired)
    screen_seed = int(np.random.default_rng([seed, 1]).integers(2**63))  # the selection's first draw: its screening samples
    mc = MonteCarlo(POINTS, loc, samples_for(config.samples, n), screen_seed, config.mc_start)
    e_max = float(mc.localization_errors(estimate, desired, [Plan.equal(np.arange(n), 0)])[0])
    bar = max(s.p_s for s in result.scores if s.plan is not None)
    discarded = [s for s in result.scores if s.n_anchors > 0 and not s.searched]
    for s in discarded:
        plans = [p for p in enumerate_plans(n, s.n_anchors) if plan_keeps_connectivity(p, estimate.positions, desired, 0.5)]
        best = float(mc.localization_errors(estimate, desired, plans).min())
        assert math.isclose(s.e_l, float(mc.localization_errors(estimate, desired, [s.plan])[0]), rel_tol=1e-9)  # same samples
        p_s_best = w_v * speed_performance(n, s.n_anchors) - (1.0 - w_v) * best / e_max
        assert p_s_best < bar, f"n_a = {s.n_anchors} could win: best P_s {p_s_best:.4f} >= {bar:.4f}"
    assert discarded  # these steps exercise the bound


def test_the_bound_discards_counts_and_a_zero_margin_discards_more():
    estimate, desired = step_problem(6, 0)
    loc = make_localizer("paper", POINTS)
    margin = AnchorSelector(POINTS, loc, SelectionConfig(w_v=0.3, w_l=0.7, genetic_gate="off"), seed=0).select(estimate, desired)
    none = AnchorSelector(POINTS, loc, SelectionConfig(w_v=0.3, w_l=0.7, genetic_gate="off", prune_gain=0.0), seed=0).select(estimate, desired)
    assert sum(s.searched for s in none.scores) <= sum(s.searched for s in margin.scores)
    everything = AnchorSelector(POINTS, loc, SelectionConfig(w_v=0.3, w_l=0.7, genetic_gate="off", prune_gain=1.0), seed=0).select(estimate, desired)
    assert all(s.searched for s in everything.scores if s.n_anchors > 0)


def test_repair_clears_crowded_heuristic_plans_with_few_swaps():
    estimate, desired = step_problem(10, 0, BODIES)
    bodies = BodyCheck.of_estimate(BODIES, estimate, desired)
    pairs = PairTable(bodies)

    def connected(plan: Plan) -> bool:
        return plan_keeps_connectivity(plan, estimate.positions, desired, BODIES.sensing_range_m)

    for n_a in (5, 8):  # n_a = 9 has 20 pairs over the contact bound (docs/bodies.md): more than 8 swaps clear
        seed = heuristic_plan(estimate.positions, desired, n_a)
        assert not bodies.is_clear(seed.groups) and conflicts(seed, pairs)[0] > 0
        fixed = repair(seed, pairs, connected)
        assert fixed is not None and bodies.is_clear(fixed.groups) and connected(fixed) and conflicts(fixed, pairs) == (0, set())
        moved = sum(a != b for a, b in zip(seed.key(), fixed.key(), strict=True))
        assert 1 <= moved <= 2 * 8  # groups changed by at most 8 swaps
    assert repair(seed, PairTable(BodyCheck(POINTS, estimate.positions, desired)), connected) is seed  # point robots: nothing to repair


@pytest.mark.parametrize("gate", ["auto", "on"])
def test_selection_is_deterministic_for_a_seed(gate):
    estimate, desired = step_problem(10, 1, BODIES)  # n_a = 0 crowded: every count searched, seeds repaired
    loc = make_localizer("paper", BODIES)
    runs = [AnchorSelector(BODIES, loc, SelectionConfig(genetic_gate=gate), seed=7).select(estimate, desired) for _ in range(2)]
    assert runs[0].plan.key() == runs[1].plan.key() and runs[0].evaluations == runs[1].evaluations
    assert [(s.n_anchors, s.e_l, s.p_s, s.searched, s.genetic) for s in runs[0].scores] == \
        [(s.n_anchors, s.e_l, s.p_s, s.searched, s.genetic) for s in runs[1].scores]
    assert any(s.searched for s in runs[0].scores)


def test_bench_select_reports_which_selections_searched_and_keeps_its_keys():
    result = bench_select(SelectBenchOptions(sizes=(6,), repeats=2, one_core=False, run=RunOptions(model=POINTS), search_all=True))
    row = result.to_json()["results"][0]
    assert list(row)[:6] == ["n", "s_median", "s_min", "s_max", "n_a", "evaluations"]  # the keys before these additions, in order
    assert row["n_searched"] == 2 and all(row["searched"]) and row["s_max_searched"] == row["s_max"]
    assert all(set(g) <= set(s) for g, s in zip(row["genetic"], row["searched"], strict=True))
