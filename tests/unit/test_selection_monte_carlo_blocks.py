"""The Monte Carlo over several sample sets and plans of different step counts in one pass gives every sample the e_l
its own set and plan give alone, to the last bit (the selection fuses its screening and its fresh checks this way).
A single sample simulated alone is the exception (numpy's products of one matrix round differently): the selection's
sets have two samples at least."""

from __future__ import annotations

import math

import numpy as np
import pytest

from coordinator.localization import make_localizer
from coordinator.plan import Plan
from coordinator.selection.heuristic import heuristic_plan
from coordinator.selection.monte_carlo import MonteCarlo, block_errors
from runtime.models.config import ModelConfig
from runtime.models.state import SwarmEstimate
from runtime.models.trajectory import body_spacing, random_trajectory

CFG = ModelConfig()


@pytest.mark.parametrize(("localizer", "start", "correlated"), [("joint", "known", False), ("paper", "estimate", True)])
def test_one_pass_over_blocks_and_step_counts_is_each_alone(localizer, start, correlated):
    n = 8
    traj = random_trajectory(n, 1, np.random.default_rng([3, n]), sensing_range=CFG.sensing_range_m, **body_spacing(CFG))
    estimate = SwarmEstimate.isotropic(traj.ids, traj.initial_poses, 0.01, math.radians(2.0))
    if correlated:  # a joint covariance with cross terms: the initial truths come from it
        rng = np.random.default_rng(1)
        mix = np.eye(3 * n) + 0.3 * rng.normal(size=(3 * n, 3 * n)) / math.sqrt(3 * n)
        estimate = SwarmEstimate.from_joint(traj.ids, traj.initial_poses, mix @ np.diag(np.tile([1e-4, 1e-4, 1e-3], n)) @ mix.T)
    desired = traj.configurations[0]
    plans = [Plan.equal(np.arange(n), 0), heuristic_plan(estimate.positions, desired, 4), heuristic_plan(estimate.positions, desired, 6)]
    assert len({p.n_steps for p in plans}) == 3
    blocks = [(4, 11), (2, 12), (6, 2**62 + 5)]
    loc = make_localizer(localizer, CFG)
    fused = block_errors(CFG, loc, start, blocks, estimate, desired, plans)
    alone = np.concatenate([np.stack([MonteCarlo(CFG, loc, count, seed, start).localization_errors(estimate, desired, [p], per_sample=True)[0]
                                      for p in plans]) for count, seed in blocks], axis=1)
    assert fused.shape == (3, 12)
    assert np.array_equal(fused, alone)
    assert len(np.unique(fused)) == fused.size  # plans and samples differ
