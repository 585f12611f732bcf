"""The anchor search's Cramer-Rao prediction, assembled densely for many plans at once, is the bound of the sparse
single-swarm assembly (``localization.crlb``) to rounding, step by step and plan by plan."""

from __future__ import annotations

import math

import numpy as np

from coordinator.localization.crlb import crlb_pose_covariances
from coordinator.plan import enumerate_plans
from coordinator.selection.crlb_rank import crlb_blocks, predicted_error, predicted_errors
from runtime.models.config import ModelConfig
from runtime.models.state import SwarmEstimate
from runtime.models.trajectory import body_spacing, random_trajectory

CFG = ModelConfig()


def test_dense_bounds_of_many_swarms_are_the_sparse_bound_of_each():
    rng = np.random.default_rng(4)
    c, n = 3, 7
    poses = rng.uniform(0.0, 0.25, (c, n, 3))
    poses[..., 2] = rng.uniform(-np.pi, np.pi, (c, n))
    poses[:, :, 2] = np.where(rng.random((c, n)) < 0.3, np.pi - 1e-9, poses[:, :, 2])  # headings at +-pi
    poses[1, 3, :2] = poses[1, 2, :2] + [CFG.sensing_range_m, 0.0]  # a pair at the sensing range
    mix = rng.normal(size=(c, n, 3, 3)) * [0.01, 0.01, 0.03]
    cov = mix @ np.swapaxes(mix, -1, -2) + np.eye(3) * 1e-8  # correlated position and heading errors
    cov[0, 1] = np.diag([1e-4, 1e-4, 0.0])  # an exact heading
    dense = crlb_blocks(poses, cov, CFG)
    for k in range(c):
        gap = np.linalg.norm(poses[k, :, None, :2] - poses[k, None, :, :2], axis=-1)
        observer, observed = np.nonzero((gap <= CFG.sensing_range_m) & ~np.eye(n, dtype=bool))
        sparse = crlb_pose_covariances(poses[k], cov[k], observer, observed, CFG)
        np.testing.assert_allclose(dense[k], sparse, rtol=1e-9, atol=1e-20)


def test_plans_predicted_together_are_each_predicted_alone():
    n = 8
    traj = random_trajectory(n, 1, np.random.default_rng([9, n]), sensing_range=CFG.sensing_range_m, **body_spacing(CFG))
    estimate = SwarmEstimate.isotropic(traj.ids, traj.initial_poses, 0.01, math.radians(2.0))
    plans = [*enumerate_plans(n, 4)[:3], *enumerate_plans(n, 7)[:2]]  # 2 and 8 steps side by side
    together = predicted_errors(CFG, estimate, traj.configurations[0], plans)
    alone = [predicted_error(CFG, estimate, traj.configurations[0], np.stack([p.moving(k) for k in range(p.n_steps)])) for p in plans]
    np.testing.assert_allclose(together, alone, rtol=1e-12)
    assert len(set(together.tolist())) == len(plans)
