"""With bodies the search returns a clear plan at a count whose heuristic plan is crowded, wherever one exists
(docs/bodies.md, docs/selection.md): config 8 of ``swarm study selection --robots 8 --seed 4242``, n_a = 6, where 72
of the 2520 plans keep bodies clear and connected; with the joint localizer the genetic gate is off there, so
the repaired heuristic plan alone found none."""

from dataclasses import replace

import numpy as np

from coordinator.localization import make_localizer
from coordinator.plan import enumerate_plans
from coordinator.selection.heuristic import heuristic_plan
from coordinator.selection.monte_carlo import plan_keeps_connectivity
from coordinator.selection.selector import AnchorSelector, SelectionConfig
from inchworm.studies.anchors import Job, experiment_setup
from runtime.models.bodies import BodyCheck
from runtime.models.config import ModelConfig

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
