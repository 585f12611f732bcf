"""Known answers for the joint problem's normal equations (coordinator/localization/joint_normal.py)
and the Levenberg-Marquardt driver they feed (sparse_lm.minimize).

The reference is built in the test from the formulas of range_bearing's docstring: whitened
residuals (prior W (p - mu), range (|d| - rho) / s_r, bearing wrap(atan2 d - theta_i - phi) / s_b(rho)),
their Jacobian J by central differences, Huber weights w = min(1, h / |r|) written out; then
J^T W J, J^T W r and the Huber cost are compared with ``JointProblem.evaluate``.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.sparse as sp

from coordinator.localization.joint_normal import JointProblem
from coordinator.localization.range_bearing import joint_sqrt_information, sqrt_information
from coordinator.localization.sparse_lm import DENSE_LIMIT, NormalEquations, add_diagonal, dense, minimize
from runtime.models.config import ModelConfig

CFG = ModelConfig(range_sigma_m=0.01, bearing_sigma_rad=0.02)


def wrap(a):
    return (a + np.pi) % (2 * np.pi) - np.pi


def reference_residuals(x, mean, w, joint, obs):
    """Whitened prior residuals then (range, bearing) per observation, from the formulas."""
    p = x.reshape(-1, 3)
    diff = p - mean
    diff[:, 2] = wrap(diff[:, 2])
    prior = w @ diff.ravel() if joint else np.einsum("nab,nb->na", w, diff).ravel()
    out = []
    for i, j, r, b in zip(*obs, strict=True):
        dx, dy = p[j, 0] - p[i, 0], p[j, 1] - p[i, 1]
        s_b = 0.02 * math.sqrt(1 + (0.03 / r) ** 4)
        out += [(math.hypot(dx, dy) - r) / 0.01, wrap(math.atan2(dy, dx) - p[i, 2] - b) / s_b]
    return prior, np.array(out)


def numeric_jacobian(f, x, h=1e-7):
    return np.column_stack([(f(x + h * e) - f(x - h * e)) / (2 * h) for e in np.eye(len(x))])


def huber(r, h):
    """(weights, cost) of whitened residuals r: w = 1 inside h, h / |r| beyond; cost r^2 / 2 or h |r| - h^2 / 2."""
    if h is None:
        return np.ones_like(r), 0.5 * float(r @ r)
    a = np.abs(r)
    return np.where(a <= h, 1.0, h / a), float(np.sum(np.where(a <= h, 0.5 * r * r, h * a - 0.5 * h * h)))


def swarm(n: int, seed: int):
    """n robots on a 0.25 m grid (jittered), each observing its grid neighbours within 0.4 m, noisy data."""
    rng = np.random.default_rng(seed)
    side = math.ceil(math.sqrt(n))
    grid = 0.25 * np.column_stack([np.arange(n) % side, np.arange(n) // side])
    truth = np.column_stack([grid + rng.uniform(-0.03, 0.03, (n, 2)), rng.uniform(-np.pi, np.pi, n)])
    d = np.hypot(*(truth[None, :, :2] - truth[:, None, :2]).transpose(2, 0, 1))
    i, j = np.nonzero((d < 0.4) & (d > 0))
    rho = d[i, j] + rng.normal(0, 0.01, len(i))
    phi = wrap(np.arctan2(truth[j, 1] - truth[i, 1], truth[j, 0] - truth[i, 0]) - truth[i, 2] + rng.normal(0, 0.02, len(i)))
    mean = truth + rng.normal(0, 0.02, truth.shape)
    return truth, mean, (i, j, rho, phi)


@pytest.mark.parametrize(
    ("n", "joint", "h"),
    [(4, False, None), (4, True, None), (4, False, 1.0), (4, True, 0.5), (25, False, None), (25, False, 1.0)],
)
def test_normal_equations_match_the_residual_reference(n, joint, h):
    """Small (dense) and 25-robot (75 unknowns: sparse) problems, per-robot and joint priors, with and
    without Huber: cost, J^T W J, J^T W r and the observations' H^T W H equal the reference."""
    truth, mean, obs = swarm(n, n + (7 if joint else 0))
    rng = np.random.default_rng(1)
    if joint:
        a = rng.normal(size=(3 * n, 3 * n)) * 0.01
        w = joint_sqrt_information(a @ a.T + 1e-4 * np.eye(3 * n))
    else:  # correlated per-robot covariances: W is not symmetric
        a = rng.normal(size=(n, 3, 3)) * 0.01
        w = sqrt_information(a @ np.swapaxes(a, 1, 2) + np.diag([2e-4, 2e-4, 2e-3]))
    problem = JointProblem(mean, w, *obs, CFG, huber=h)
    assert problem.dense == (joint or 3 * n <= DENSE_LIMIT)
    x = (truth + rng.normal(0, 0.01, truth.shape)).ravel()
    def flat(v):
        return np.concatenate(reference_residuals(v, mean, w, joint, obs))

    r = flat(x)
    jac = numeric_jacobian(flat, x)
    weights, cost = huber(r, h)
    ne = problem.evaluate(x)
    assert isinstance(ne, NormalEquations) and ne.curvature is None
    assert ne.cost == pytest.approx(cost, rel=1e-9)
    scale = np.abs(jac.T @ (weights[:, None] * jac)).max()
    np.testing.assert_allclose(dense(ne.normal), jac.T @ (weights[:, None] * jac), atol=1e-6 * scale)
    np.testing.assert_allclose(ne.gradient, jac.T @ (weights * r), atol=1e-6 * np.abs(jac.T @ (weights * r)).max())
    k = 3 * n
    h_obs = jac[k:]
    obs_normal = h_obs.T @ (weights[k:, None] * h_obs)
    np.testing.assert_allclose(dense(problem.observation_normal(ne.extra)), obs_normal, atol=1e-6 * scale)
    prior, obs_res = problem.residuals(x)
    np.testing.assert_allclose(prior, r[:k], atol=1e-12)
    np.testing.assert_allclose(obs_res.ravel(), r[k:], atol=1e-9)
    assert sp.issparse(ne.normal) != problem.dense


@pytest.mark.parametrize("n", [4, 25, 40])
def test_solve_is_the_shifted_linear_solve(n):
    """(J^T J + diag(shift)) dx = rhs, dense (small), sparse (25 robots), dense Cholesky with a joint prior
    (40 robots, 120 unknowns); the sparse solver refactorizes numerically on later calls."""
    truth, mean, obs = swarm(n, 3)
    if n == 40:
        w = joint_sqrt_information(np.kron(np.eye(n), np.diag([4e-4, 4e-4, 2.5e-3])) + 1e-6)
    else:
        w = sqrt_information(np.broadcast_to(np.diag([4e-4, 4e-4, 2.5e-3]), (n, 3, 3)).copy())
    problem = JointProblem(mean, w, *obs, CFG)
    rng = np.random.default_rng(2)
    for _ in range(2):
        ne = problem.evaluate((truth + rng.normal(0, 0.01, truth.shape)).ravel())
        shift = rng.uniform(0, 1, 3 * n)
        rhs = rng.normal(size=3 * n)
        want = np.linalg.solve(dense(ne.normal) + np.diag(shift), rhs)
        np.testing.assert_allclose(problem.solve(ne.normal, shift, rhs), want, rtol=1e-8, atol=1e-12)


def test_minimize_with_normal_equations_of_a_linear_problem():
    """Least squares A x = b (3 equations, 2 unknowns) through ``minimize``: the normal-equation solution
    x = (A^T A)^-1 A^T b, A = [[1, 0], [0, 1], [1, 1]], b = (1, 2, 4): x = (4/3, 7/3), cost 0.5 |A x - b|^2
    = 0.5 (1/9 + 1/9 + 1/9) = 1/6; the problem's ``extra`` comes back; a custom ``solve`` is used."""
    a = np.array([[1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
    b = np.array([1.0, 2.0, 4.0])
    shifts = []

    def evaluate(x):
        r = a @ x - b
        return NormalEquations(0.5 * float(r @ r), a.T @ a, a.T @ r, None, "here")

    def solve(m, shift, rhs):
        shifts.append(shift.copy())
        return np.linalg.solve(m + np.diag(shift), rhs)

    out = minimize(evaluate, np.zeros(2), solve=solve)
    np.testing.assert_allclose(out.x, [4 / 3, 7 / 3], atol=1e-9)
    assert out.cost == pytest.approx(1 / 6) and out.extra == "here" and out.converged
    np.testing.assert_array_equal(out.normal_matrix, a.T @ a)
    np.testing.assert_allclose(shifts[0], 1e-8 * np.array([2.0, 2.0]))  # mu = 1e-8 times diag(A^T A)


def test_minimize_adds_the_curvature_clamped_at_minus_90_percent():
    """A curvature of -1e6 against J^T J = 1. The first iteration is Gauss-Newton: its solve sees 1 + 1e-8
    (the step 3 / (1 + 1e-8) is accepted, mu -> 1e-9); the second adds the curvature clamped to -0.9,
    so its solve sees 1 - 0.9 + 1e-9."""
    seen = []

    def evaluate(x):
        r = x - 3.0
        return NormalEquations(0.5 * float(r @ r), np.eye(1), r, np.array([-1e6]))

    def solve(m, shift, rhs):
        seen.append(float(m[0, 0] + shift[0]))
        return np.linalg.solve(m + np.diag(shift), rhs)

    minimize(evaluate, np.zeros(1), solve=solve, max_iter=2)
    assert seen[0] == pytest.approx(1 + 1e-8, rel=1e-12)
    assert seen[1] == pytest.approx(0.1 + 1e-9, rel=1e-12)


def test_add_diagonal_dense_and_sparse():
    """[[1, 2], [3, 4]] + diag(10, 20) = [[11, 2], [3, 24]], the input unchanged, sparse stays sparse."""
    a = np.array([[1.0, 2.0], [3.0, 4.0]])
    np.testing.assert_array_equal(add_diagonal(a, np.array([10.0, 20.0])), [[11, 2], [3, 24]])
    assert a.tolist() == [[1, 2], [3, 4]]
    out = add_diagonal(sp.csr_matrix(a), np.array([10.0, 20.0]))
    assert sp.issparse(out) and out.toarray().tolist() == [[11, 2], [3, 24]]


def test_dense_solve_falls_back_when_cholesky_fails():
    """The dense solve (here a joint prior, 75 unknowns) uses Cholesky (LAPACK dposv); a matrix that is not
    positive definite (here -I, shift 0) goes to the general solver: -I dx = rhs gives dx = -rhs."""
    truth, mean, obs = swarm(25, 4)
    w = joint_sqrt_information(np.kron(np.eye(25), np.diag([4e-4, 4e-4, 2.5e-3])))
    problem = JointProblem(mean, w, *obs, CFG)
    assert problem.dense and problem.size == 75
    rhs = np.arange(75.0)
    np.testing.assert_allclose(problem.solve(-np.eye(75), np.zeros(75), rhs), -rhs)


@pytest.mark.parametrize("n", [4, 25])
def test_observation_normal_when_the_last_robot_observes_nobody(n):
    """The last robot is observed but observes nobody (its heading enters no observation): H^T H still has
    the full (3n, 3n) shape, with a zero row and column for that heading."""
    truth, mean, (i, j, rho, phi) = swarm(n, 5)
    keep = i != n - 1
    obs = (i[keep], j[keep], rho[keep], phi[keep])
    w = sqrt_information(np.broadcast_to(np.diag([4e-4, 4e-4, 2.5e-3]), (n, 3, 3)).copy())
    problem = JointProblem(mean, w, *obs, CFG)
    x = truth.ravel()
    h = numeric_jacobian(lambda v: reference_residuals(v, mean, w, False, obs)[1], x)
    got = dense(problem.observation_normal(problem.evaluate(x).extra))
    assert got.shape == (3 * n, 3 * n)
    np.testing.assert_allclose(got, h.T @ h, atol=1e-6 * np.abs(h.T @ h).max())
    np.testing.assert_array_equal(got[-1], 0.0)
