"""The joint problem's normal equations, assembled from per-observation blocks, against J^T J and J^T r
of the residual formulation (range_bearing's whitened residuals and Jacobian triplets), dense and sparse."""

from __future__ import annotations

import numpy as np
import pytest

from coordinator.localization.dead_reckoning import dead_reckon
from coordinator.localization.joint import block_diagonal
from coordinator.localization.joint_normal import JointProblem
from coordinator.localization.range_bearing import (
    joint_prior_terms,
    joint_sqrt_information,
    observation_terms,
    prior_terms,
    sqrt_information,
    stack_terms,
)
from coordinator.localization.sparse_lm import PoseLayout, dense
from runtime.models.config import ModelConfig
from runtime.models.scenarios import random_step

CFG = ModelConfig()


def _case(n: int, seed: int, joint_prior: bool):
    case = random_step(n, CFG, np.random.default_rng(seed), spacing=0.22, seed=seed)
    dr = dead_reckon(case.prior, case.step, CFG)
    i, j = case.observations.indexed(case.prior.ids)
    if joint_prior:  # a correlated joint covariance: the block-diagonal one plus a shared component
        rng = np.random.default_rng(seed + 1)
        a = rng.normal(size=(3 * n, 2)) * 0.01
        u = joint_sqrt_information(block_diagonal(dr.cov) + a @ a.T)
    else:
        u = sqrt_information(dr.cov)
    return dr.poses, u, i, j, case.observations


def _reference(x: np.ndarray, mean, u, i, j, obs, huber):
    """Cost, J^T J, J^T r of the stacked whitened residuals, with Huber IRLS weights (sparse_lm's rules)."""
    n = len(mean)
    layout = PoseLayout(np.ones(n, bool), np.ones(n, bool))
    poses = layout.unpack(x, mean)
    prior = (joint_prior_terms if u.ndim == 2 else prior_terms)(poses, layout, mean, u)
    r, jac = stack_terms(layout.size, prior, observation_terms(poses, layout, i, j, obs.range_m, obs.bearing_rad, CFG))
    jac = dense(jac)
    if huber is None:
        w, cost = np.ones_like(r), 0.5 * r @ r
    else:
        a = np.abs(r)
        w = np.where(a <= huber, 1.0, huber / a)
        cost = np.sum(np.where(a <= huber, 0.5 * r * r, huber * a - 0.5 * huber**2))
    return cost, jac.T @ (w[:, None] * jac), jac.T @ (w * r), jac[3 * n :], w[3 * n :]


@pytest.mark.parametrize("n", [8, 30])  # dense (24 unknowns) and sparse (90) assembly
@pytest.mark.parametrize("joint_prior", [False, True])
@pytest.mark.parametrize("huber", [None, 1.0])
def test_normal_equations_equal_those_of_the_residual_formulation(n, joint_prior, huber):
    mean, u, i, j, obs = _case(n, 3, joint_prior)
    problem = JointProblem(mean, u, i, j, obs.range_m, obs.bearing_rad, CFG, huber)
    x = mean.ravel() + np.random.default_rng(4).normal(0, 0.02, 3 * n)  # away from the prior: Huber bites
    ne = problem.evaluate(x)
    cost, normal, gradient, h, w_obs = _reference(x, mean, u, i, j, obs, huber)
    assert ne.cost == pytest.approx(cost, rel=1e-12)
    np.testing.assert_allclose(dense(ne.normal), normal, rtol=1e-10, atol=1e-9 * np.abs(normal).max())
    np.testing.assert_allclose(ne.gradient, gradient, rtol=1e-10, atol=1e-9 * np.abs(gradient).max())
    np.testing.assert_allclose(dense(problem.observation_normal(ne.extra)), h.T @ (w_obs[:, None] * h),
                               rtol=1e-10, atol=1e-9 * np.abs(normal).max())
    if huber is not None:
        assert np.any(w_obs < 1.0)  # the case exercises the down-weighting
    prior_r, obs_r = problem.residuals(x)
    assert obs_r.shape == (len(i), 2)
    assert 0.5 * (prior_r @ prior_r + np.sum(obs_r**2)) == pytest.approx(_reference(x, mean, u, i, j, obs, None)[0], rel=1e-12)


@pytest.mark.parametrize("n", [8, 30])
def test_solve_is_the_damped_system(n):
    mean, u, i, j, obs = _case(n, 5, False)
    problem = JointProblem(mean, u, i, j, obs.range_m, obs.bearing_rad, CFG)
    ne = problem.evaluate(mean.ravel())
    shift = np.random.default_rng(6).uniform(0.0, 1.0, 3 * n) * np.abs(ne.normal.diagonal())
    want = np.linalg.solve(dense(ne.normal) + np.diag(shift), -ne.gradient)
    for _ in range(2):  # the second call refactorizes numerically on the kept pattern
        np.testing.assert_allclose(problem.solve(ne.normal, shift, -ne.gradient), want, rtol=1e-9, atol=1e-12)
        shift = shift * 0.5
        want = np.linalg.solve(dense(ne.normal) + np.diag(shift), -ne.gradient)


def test_the_pattern_is_ranked_alike_by_the_count_map_and_by_sorting(monkeypatch):
    """Up to ``RANK_MAP_LIMIT`` entries the pattern's keys are ranked by marking and counting, above by
    sorting and searching: both must give the same CSR pattern and the same entry positions."""
    import coordinator.localization.joint_normal as jn

    mean, u, i, j, obs = _case(30, 7, False)
    by_map = JointProblem(mean, u, i, j, obs.range_m, obs.bearing_rad, CFG)
    monkeypatch.setattr(jn, "RANK_MAP_LIMIT", 0)
    by_sort = JointProblem(mean, u, i, j, obs.range_m, obs.bearing_rad, CFG)
    for name in ("_indices", "_indptr", "_obs_pos", "_prior_pos", "_lower_at", "_lower_diag"):
        np.testing.assert_array_equal(getattr(by_map, name), getattr(by_sort, name), err_msg=name)
    for name in ("indices", "indptr"):
        np.testing.assert_array_equal(getattr(by_map._upper, name), getattr(by_sort._upper, name), err_msg=name)
    x = mean.ravel() + np.random.default_rng(8).normal(0, 0.02, 90)
    np.testing.assert_array_equal(dense(by_map.evaluate(x).normal), dense(by_sort.evaluate(x).normal))
