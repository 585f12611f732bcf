"""Work the selection skips once it cannot change the outcome (docs/selection.md, steps 3-4), on step 1 of
``swarm bench select --sizes 10 --localizer joint``: n_a = 0 and 9 are crowded, n_a = 5 has a crowded heuristic plan
that no repair makes clear and 8 clear plans, n_a = 8 a repaired seed."""

import math

import numpy as np
import pytest

from coordinator.localization import make_localizer
from coordinator.plan import Plan, enumerate_plans, speed_performance
from coordinator.selection import selector as selector_module
from coordinator.selection.monte_carlo import MonteCarlo, plan_keeps_connectivity
from coordinator.selection.racing import EARLY_MARGIN, fresh_blocks
from coordinator.selection.selector import AnchorSelector, SelectionConfig, samples_for
from runtime.models.bodies import BodyCheck
from runtime.models.config import ModelConfig
from runtime.models.state import SwarmEstimate
from runtime.models.trajectory import body_spacing, random_trajectory

CFG = ModelConfig()


@pytest.fixture(scope="module")
def step_one():
    """(estimate, desired, the selection, the starting count of each genetic search, the plans of each race)."""
    traj = random_trajectory(10, 1, np.random.default_rng([0, 10, 1]), sensing_range=CFG.sensing_range_m, **body_spacing(CFG))
    estimate = SwarmEstimate.isotropic(traj.ids, traj.initial_poses, 0.01, math.radians(2.0))
    searched, raced = [], []
    search, race = selector_module.genetic_search, selector_module.race

    def search_spy(evaluate, starts, *args, **kwargs):
        searched.append(starts[0].n_anchors)
        return search(evaluate, starts, *args, **kwargs)

    def race_spy(plans, *args, **kwargs):
        raced.append(plans)
        return race(plans, *args, **kwargs)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(selector_module, "genetic_search", search_spy)
        patch.setattr(selector_module, "race", race_spy)
        result = AnchorSelector(CFG, make_localizer("joint", CFG), SelectionConfig(), seed=1).select(estimate, traj.configurations[0])
    return estimate, traj.configurations[0], result, searched, raced


def test_a_count_whose_every_feasible_plan_is_a_contender_is_raced_without_a_genetic_search(step_one):
    estimate, desired, result, searched, raced = step_one
    bodies = BodyCheck.of_estimate(CFG, estimate, desired)
    clear = {p.key() for p in enumerate_plans(10, 5)
             if bodies.is_clear(p.groups) and plan_keeps_connectivity(p, estimate.positions, desired, CFG.sensing_range_m)}
    assert 1 < len(clear) <= SelectionConfig().contenders
    assert 5 not in searched and 8 in searched  # n_a = 8 has more plans than its starts: searched
    assert {p.key() for p in raced[0]} == clear  # n_a = 5: every clear plan raced
    assert result.n_anchors == 5 and result.plan.key() in clear


def test_a_seedless_count_looks_at_the_fresh_set_until_its_p_s_is_decided(step_one):
    """n_a = 5 has no seed: its race winner is scored on the fresh set after every count's search, block by block,
    and stops at the first look where its P_s is more than ``EARLY_MARGIN`` standard errors from the others' best."""
    estimate, desired, result, _, _ = step_one
    sel = SelectionConfig()
    five = next(s for s in result.scores if s.n_anchors == 5)
    other = max(s.p_s for s in result.scores if s.n_anchors != 5 and s.plan is not None)
    assert result.fresh_seed is not None and five.plan is not None and np.isfinite(other)
    blocks = fresh_blocks(samples_for(sel.final_samples, 10), result.fresh_seed, sel.final_looks)
    mc = [MonteCarlo(CFG, make_localizer("joint", CFG), m, s, sel.mc_start) for m, s in blocks]
    plans = [five.plan, Plan.equal(np.arange(10), 0)]
    per = np.zeros((2, 0))
    for look, block in enumerate(mc):  # the looks up to the one whose e_l was reported
        per = np.concatenate([per, block.localization_errors(estimate, desired, plans, per_sample=True)], axis=1)
        p_s = sel.w_v * speed_performance(10, 5) - sel.w_l * per[0] / per[1].mean()
        decided = abs(p_s.mean() - other) > EARLY_MARGIN * p_s.std(ddof=1) / np.sqrt(per.shape[1])
        if np.isclose(per[0].mean(), five.e_l, rtol=1e-12, atol=0):
            assert decided and look < len(blocks) - 1 and np.isclose(p_s.mean(), five.p_s, rtol=1e-12)
            return
        assert not decided  # an earlier look would have stopped
    raise AssertionError("the reported e_l is on no look of the fresh set")
