"""The pair verdict tables (``BodyCheck.pair_tables``, from the regrouping's ``pair_risks``) judge every plan as
``BodyCheck`` does step by step (constraint g of Eq. 4), at one bound and at bounds per robot."""

from __future__ import annotations

import math

import numpy as np
import pytest

from coordinator.plan import enumerate_plans
from coordinator.selection.clear_pairs import PairTable
from runtime.models.bodies import BodyCheck
from runtime.models.config import ModelConfig
from runtime.models.state import SwarmEstimate
from runtime.models.trajectory import body_spacing, random_trajectory

BODIES = ModelConfig()  # default radius: bodies on


def step_by_step(bodies: BodyCheck, groups: list[np.ndarray]) -> list[int]:
    before, out = bodies.current.copy(), []
    for group in groups:
        moving = np.zeros(len(before), bool)
        moving[group] = True
        out.append(len(bodies.step_conflicts(before, moving)))
        before[group] = bodies.desired[group]
    return out


@pytest.mark.parametrize(("n", "n_a", "seed", "levels"), [(8, 4, 0, False), (8, 6, 1, True), (10, 5, 2, False), (9, 6, 3, True)])
def test_the_tables_judge_every_plan_as_the_body_check_does(n, n_a, seed, levels):
    traj = random_trajectory(n, 1, np.random.default_rng([7, n, seed]), sensing_range=BODIES.sensing_range_m, **body_spacing(BODIES))
    rng = np.random.default_rng(seed)
    mix = np.eye(3 * n) + 0.3 * rng.normal(size=(3 * n, 3 * n)) / math.sqrt(3 * n)
    joint = mix @ np.diag(np.tile([0.01**2, 0.01**2, math.radians(2.0) ** 2], n)) @ mix.T  # correlated errors
    estimate = SwarmEstimate.from_joint(traj.ids, traj.initial_poses, joint)
    bodies = BodyCheck.of_estimate(BODIES, estimate, traj.configurations[0])
    if levels:  # bounds per robot, as the regrouping raises them
        bodies = bodies.with_levels(rng.choice([1e-3, 1e-3, 1e-2, 1e-1], n))
    plans = enumerate_plans(n, n_a)
    plans = [plans[k] for k in rng.choice(len(plans), min(len(plans), 150), replace=False)]
    table = PairTable(bodies)
    assert np.array_equal(table.together, table.together.T)  # a pair of movers is one verdict
    verdicts = [bodies.is_clear(p.groups) for p in plans]
    assert 0 < sum(verdicts) < len(plans)  # both kinds of plan are judged
    assert table.clear(plans).tolist() == verdicts
    assert all(table.step_counts(p) == step_by_step(bodies, p.groups) for p in plans[:40])


def test_point_robots_have_no_conflicting_pair():
    n = 6
    traj = random_trajectory(n, 1, np.random.default_rng(5), sensing_range=BODIES.sensing_range_m, **body_spacing(BODIES))
    estimate = SwarmEstimate.isotropic(traj.ids, traj.initial_poses, 0.01, math.radians(2.0))
    bodies = BodyCheck.of_estimate(ModelConfig(robot_radius_m=0.0), estimate, traj.configurations[0])
    assert not any(t.any() for t in bodies.pair_tables())
    assert PairTable(bodies).clear(enumerate_plans(n, 3)[:20]).all()
