"""With bodies the search returns a clear plan at a count whose heuristic plan is crowded, wherever one exists
(docs/bodies.md, docs/selection.md): config 8 of ``swarm study selection --robots 8 --seed 4242``, n_a = 6, where 72
of the 2520 plans keep bodies clear and connected; with the joint localizer the genetic gate is off there, so
the repaired heuristic plan alone found none."""

import math
from dataclasses import replace

import numpy as np

from coordinator.localization import make_localizer
from coordinator.plan import enumerate_plans
from coordinator.selection import selector as selector_module
from coordinator.selection.heuristic import heuristic_plan
from coordinator.selection.monte_carlo import plan_keeps_connectivity
from coordinator.selection.selector import AnchorSelector, SelectionConfig
from inchworm.studies.anchors import Job, experiment_setup
from runtime.models.bodies import BodyCheck
from runtime.models.config import ModelConfig
from runtime.models.state import SwarmEstimate
from runtime.models.trajectory import body_spacing, random_trajectory

CFG = ModelConfig()


def test_a_crowded_count_returns_a_clear_plan_where_one_exists():
    _, start, desired, estimate, _ = experiment_setup(Job(8, 8, 8, 4242, CFG, "joint"))
    bodies = BodyCheck.of_estimate(CFG, estimate, desired)

    def feasible(plan):
        return bodies.is_clear(plan.groups) and plan_keeps_connectivity(plan, estimate.positions, desired, CFG.sensing_range_m)

    assert not bodies.is_clear(heuristic_plan(estimate.positions, desired, 6).groups)
    clear = {p.key() for p in enumerate_plans(8, 6) if feasible(p)}
    assert 0 < len(clear) < 100
    selection = replace(SelectionConfig(samples=4, final_samples=16, final_looks=1), anchor_counts=(6,))
    chosen = AnchorSelector(CFG, make_localizer("joint", CFG), selection, seed=0).select(estimate, desired)
    assert chosen.plan.key() in clear and chosen.scores[0].plan is not None
    assert np.isfinite(chosen.scores[0].e_l)


def test_a_search_from_enumerated_clear_plans_races_as_many_as_an_unscreened_search(monkeypatch):
    """The screened search (joint localizer) races 2 plans; started from a population of enumerated clear plans, all
    evaluated by Monte Carlo, it races ``contenders`` of them (the best on the search's few samples is often not the best)."""
    _, start, desired, estimate, _ = experiment_setup(Job(8, 8, 8, 4242, CFG, "joint"))
    bodies = BodyCheck.of_estimate(CFG, estimate, desired)
    raced: list[list] = []
    original = selector_module.race

    def spy(plans, *args, **kwargs):
        raced.append(plans)
        return original(plans, *args, **kwargs)

    monkeypatch.setattr(selector_module, "race", spy)
    selection = replace(SelectionConfig(samples=4, final_samples=16, final_looks=1, contenders=5), anchor_counts=(6,))
    AnchorSelector(CFG, make_localizer("joint", CFG), selection, seed=0).select(estimate, desired)
    assert len(raced) == 1 and len(raced[0]) == 5
    assert all(bodies.is_clear(p.groups) for p in raced[0])


def test_a_count_that_cannot_win_stops_its_race_and_the_choice_stays(monkeypatch):
    """Step 0 of ``swarm bench select --sizes 10 --localizer joint``: n_a = 0 (P_s = 0) wins; the crowded n_a = 5 is
    searched from its enumerated clear plans, and its race's leader is clearly below P_s = 0 after the first round.
    Without the stop (the race told nothing) the race and final check run in full: the same plan is chosen, dearer."""
    traj = random_trajectory(10, 1, np.random.default_rng([0, 10, 0]), sensing_range=CFG.sensing_range_m, **body_spacing(CFG))
    estimate = SwarmEstimate.isotropic(traj.ids, traj.initial_poses, 0.01, math.radians(2.0))
    localizer = make_localizer("joint", CFG)
    stopping = AnchorSelector(CFG, localizer, SelectionConfig(), seed=0).select(estimate, traj.configurations[0])
    original = selector_module.race
    monkeypatch.setattr(selector_module, "race", lambda *args, hopeless=None, **options: original(*args, **options))
    full = AnchorSelector(CFG, localizer, SelectionConfig(), seed=0).select(estimate, traj.configurations[0])
    assert stopping.n_anchors == full.n_anchors == 0 and stopping.plan.key() == full.plan.key()
    assert [s.searched for s in stopping.scores] == [s.searched for s in full.scores]
    assert stopping.evaluations < full.evaluations
