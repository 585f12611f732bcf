"""Known answers for the joint localizer's bookkeeping: dead-reckoning propagation of the joint
covariance (dead_reckoning.py), the gauge (gauge.py), the retry logic of partial localization
(partial.py) and the covariance helpers of joint.py.

References are written out in the tests from the docstrings' formulas (the EKF predict
F P F^T + Fu Q Fu^T, the projection off the gauge, the Sylvester criterion) or worked by hand.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.sparse as sp

import coordinator.localization.joint as joint_module
from coordinator.localization.dead_reckoning import dead_reckon, dead_reckon_arrays, propagate_joint
from coordinator.localization.gauge import constrained_covariance, gauge_basis, inverse, transport
from coordinator.localization.joint import (
    JointLocalizer,
    block_diagonal,
    checked,
    pose_covariances,
    psd,
    psd_joint,
    worst_observation,
)
from coordinator.localization.partial import MAX_RETRIES, localize_observable, solvable_subset
from coordinator.localization.sparse_lm import BLAS_SMALL, PoseLayout
from runtime.errors import LocalizationError, SwarmInputError
from runtime.models.config import ModelConfig
from runtime.models.geometry import wrap_angle
from runtime.models.rng import Stream, robot_rngs
from runtime.models.sensing import sense_swarm
from runtime.models.state import Observations, StepCommands, SwarmEstimate

CFG = ModelConfig()


def spd(k: int, seed: int, scale: float = 0.01) -> np.ndarray:
    a = np.random.default_rng(seed).normal(size=(k, k)) * scale
    return a @ a.T + 1e-4 * np.eye(k)


# ---------------------------------------------------------------------------------------------
# Dead reckoning (Eq. 17-19) and the joint covariance


def test_propagate_joint_is_the_ekf_predict():
    """Robot 0 (heading 0.3) turns 0.4 and drives d = 0.2, robot 1 is an anchor, robot 2 is 'moving' with a
    zero command. With h = 0.3 + 0.4, Fx_0 = [[1, 0, -d sin h], [0, 1, d cos h], [0, 0, 1]], the others
    identity; the motion noise of robot 0 is s_t^2 u u^T + (0.05)^2 v v^T with u = (-d sin h, d cos h, 1)
    (turn) and v = (d cos h, d sin h, 0) (drive, 5 % of d); a zero command adds nothing. P' = F P F^T + Q."""
    poses = np.array([[0.0, 0.0, 0.3], [0.5, 0.1, -1.0], [0.2, 0.4, 2.0]])
    commands = np.array([[0.4, 0.2], [1.0, 0.3], [0.0, 0.0]])  # robot 1's command is ignored (not moving)
    moving = np.array([True, False, True])
    joint = spd(9, 1)
    prior = SwarmEstimate.from_joint(np.arange(3), poses, joint)
    d, h = 0.2, 0.7
    f = np.eye(9)
    f[0, 2], f[1, 2] = -d * math.sin(h), d * math.cos(h)
    u = np.array([-d * math.sin(h), d * math.cos(h), 1.0])
    v = np.array([d * math.cos(h), d * math.sin(h), 0.0])
    q = np.zeros((9, 9))
    q[:3, :3] = CFG.turn_sigma_rad**2 * np.outer(u, u) + CFG.drive_sigma_frac**2 * np.outer(v, v)
    want = f @ joint @ f.T + q
    got = propagate_joint(prior, StepCommands(np.arange(3), commands, moving), CFG)
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-18)
    np.testing.assert_array_equal(got, got.T)
    est = dead_reckon(prior, StepCommands(np.arange(3), commands, moving), CFG)
    np.testing.assert_allclose(est.joint, want, rtol=1e-12, atol=1e-18)
    np.testing.assert_allclose(est.poses[0], [d * math.cos(h), d * math.sin(h), h], atol=1e-15)
    np.testing.assert_array_equal(est.poses[1:], poses[1:])


def test_dead_reckoning_without_a_joint_prior_has_none():
    prior = SwarmEstimate.isotropic(np.arange(2), np.zeros((2, 3)), 0.01, 0.01)
    est = dead_reckon(prior, StepCommands(np.arange(2), np.array([[0.0, 0.1], [0.0, 0.0]]), np.array([True, False])), CFG)
    assert est.joint is None and est.cov[0, 0, 0] > prior.cov[0, 0, 0]
    np.testing.assert_array_equal(est.cov[1], prior.cov[1])


def test_dead_reckoning_refuses_commands_for_other_robots():
    prior = SwarmEstimate.isotropic([1, 2], np.zeros((2, 3)), 0.01, 0.01)
    with pytest.raises(SwarmInputError, match=r"step commands are for robots \[1, 3\], the estimate for \[1, 2\]"):
        dead_reckon(prior, StepCommands.stationary([1, 3]), CFG)


def test_dead_reckon_arrays_broadcasts_over_batches():
    """Two samples of two robots: a moving robot at the origin heading 0 turning pi/2 and driving 0.1 ends
    at (0, 0.1, pi/2); a robot that does not move keeps pose and covariance exactly, whatever its command."""
    poses = np.zeros((2, 2, 3))
    cov = np.broadcast_to(np.diag([1e-4, 1e-4, 1e-3]), (2, 2, 3, 3)).copy()
    commands = np.broadcast_to([math.pi / 2, 0.1], (2, 2, 2)).copy()
    moving = np.array([[True, False], [False, True]])
    out, out_cov = dead_reckon_arrays(poses, cov, commands, moving, CFG)
    np.testing.assert_allclose(out[0, 0], [0, 0.1, math.pi / 2], atol=1e-15)
    np.testing.assert_allclose(out[1, 1], [0, 0.1, math.pi / 2], atol=1e-15)
    np.testing.assert_array_equal(out[0, 1], [0, 0, 0])
    np.testing.assert_array_equal(out_cov[0, 1], cov[0, 1])
    # Moving 0.1 along y with heading variance 1e-3: x gains (0.1)^2 (1e-3 + s_t^2), y gains (0.005)^2.
    assert out_cov[0, 0, 0, 0] == pytest.approx(1e-4 + 0.01 * (1e-3 + CFG.turn_sigma_rad**2), rel=1e-9)
    assert out_cov[0, 0, 1, 1] == pytest.approx(1e-4 + 0.005**2, rel=1e-9)


# ---------------------------------------------------------------------------------------------
# The gauge


def test_gauge_basis_by_hand():
    """Robots at (1, 0) and (-1, 2): centroid (0, 1), offsets (1, -1) and (-1, 1). Columns: x translation,
    y translation, rotation (-c_y, c_x, 1) per robot. About the point (1, 0) instead: offsets (0, 0), (-2, 2)."""
    poses = np.array([[1.0, 0.0, 0.5], [-1.0, 2.0, -0.5]])
    want = np.array([
        [1, 0, 1], [0, 1, 1], [0, 0, 1],
        [1, 0, -1], [0, 1, -1], [0, 0, 1],
    ], float)
    np.testing.assert_array_equal(gauge_basis(poses), want)
    about = gauge_basis(poses, np.array([1.0, 0.0]))
    np.testing.assert_array_equal(about[:, 2], [0, 0, 1, -2, -2, 1])


def observation_jacobian(poses: np.ndarray, observer, observed, h: float = 1e-6) -> np.ndarray:
    """Central differences of (range, bearing in the observer's frame) of every observation."""

    def f(flat):
        p = flat.reshape(-1, 3)
        out = []
        for i, j in zip(observer, observed, strict=True):
            dx, dy = p[j, 0] - p[i, 0], p[j, 1] - p[i, 1]
            out += [math.hypot(dx, dy), math.atan2(dy, dx) - p[i, 2]]
        return np.array(out)

    x = poses.ravel()
    return np.column_stack([(f(x + h * e) - f(x - h * e)) / (2 * h) for e in np.eye(len(x))])


def test_observations_are_blind_to_the_gauge():
    """H N = 0: relative ranges and body-frame bearings do not change under a global translation or a
    rotation of every pose about the centroid (or any point)."""
    poses = np.array([[0.0, 0.0, 0.3], [0.3, 0.1, -1.0], [0.1, 0.35, 2.0], [0.4, 0.3, 0.0]])
    h = observation_jacobian(poses, [0, 1, 2, 3, 1], [1, 2, 3, 0, 3])
    np.testing.assert_allclose(h @ gauge_basis(poses), 0, atol=1e-8)
    np.testing.assert_allclose(h @ gauge_basis(poses, np.array([5.0, -2.0])), 0, atol=1e-8)


def test_constrained_covariance_is_the_docstring_formula():
    """(J^T J - H^T H + H~^T H~)^-1 with H~ = H (I - N (N^T N)^-1 N^T), N at the predicted poses (the
    function takes H^T H): written out with dense matrices. When the prediction is the point where H was taken (H N = 0 there), H~ = H
    and the result is the plain inverse."""
    poses = np.array([[0.0, 0.0, 0.3], [0.3, 0.1, -1.0], [0.1, 0.35, 2.0]])
    h = observation_jacobian(poses, [0, 1, 2, 0], [1, 2, 0, 2]) / 0.01
    prior_info = np.linalg.inv(spd(9, 2))
    normal = prior_info + h.T @ h
    predicted = poses + np.random.default_rng(3).normal(0, 0.05, poses.shape)
    n = gauge_basis(predicted)
    off = np.eye(9) - n @ np.linalg.solve(n.T @ n, n.T)
    want = np.linalg.inv(normal - h.T @ h + (h @ off).T @ (h @ off))
    np.testing.assert_allclose(constrained_covariance(normal, h.T @ h, predicted), want, rtol=1e-8)
    np.testing.assert_allclose(constrained_covariance(normal, h.T @ h, poses), np.linalg.inv(normal), rtol=1e-5)


def test_inverse_of_a_singular_information_is_nan():
    assert np.isnan(inverse(np.zeros((3, 3)))).all() and inverse(np.zeros((3, 3))).shape == (3, 3)
    np.testing.assert_allclose(inverse(np.diag([2.0, 4.0])), np.diag([0.5, 0.25]))


@pytest.mark.parametrize("sparse_input", [False, True])
def test_inverse_above_blas_small_by_cholesky_and_its_fallbacks(sparse_input):
    """Order 120 (>= BLAS_SMALL, the Cholesky path): 60 copies of [[2, 1], [1, 2]], whose inverse is
    [[2, -1], [-1, 2]] / 3, returned symmetric in full (potri fills one triangle only). The same
    blocks with [[1, 2], [2, 1]] (indefinite, det -3, inverse [[-1, 2], [2, -1]] / 3): Cholesky fails,
    the general inverse answers. A zero matrix of that order: NaN everywhere."""
    assert BLAS_SMALL <= 120
    as_input = (lambda m: sp.csr_matrix(m)) if sparse_input else (lambda m: m)
    spd = np.kron(np.eye(60), [[2.0, 1.0], [1.0, 2.0]])
    np.testing.assert_allclose(inverse(as_input(spd)), np.kron(np.eye(60), [[2.0, -1.0], [-1.0, 2.0]]) / 3, atol=1e-15)
    indefinite = np.kron(np.eye(60), [[1.0, 2.0], [2.0, 1.0]])
    np.testing.assert_allclose(inverse(as_input(indefinite)), np.kron(np.eye(60), [[-1.0, 2.0], [2.0, -1.0]]) / 3, atol=1e-15)
    assert np.isnan(inverse(np.zeros((120, 120)))).all()


def test_transport_moves_gauge_covariance_onto_the_new_gauge():
    """T N(predicted) = N(solution) (about the predicted centroid), so a covariance that lies entirely along
    the gauge, N(predicted) A N(predicted)^T, becomes N(solution) A N(solution)^T; with solution = prediction
    nothing moves."""
    rng = np.random.default_rng(8)
    predicted = np.column_stack([rng.uniform(-1, 1, (4, 2)), rng.uniform(-3, 3, 4)])
    solution = predicted + rng.normal(0, 0.05, (4, 3))
    center = predicted[:, :2].mean(axis=0)
    a = spd(3, 9, 1.0)
    before = gauge_basis(predicted, center) @ a @ gauge_basis(predicted, center).T
    after = gauge_basis(solution, center) @ a @ gauge_basis(solution, center).T
    np.testing.assert_allclose(transport(before, predicted, solution), after, rtol=1e-9, atol=1e-12)
    cov = spd(12, 10)
    np.testing.assert_allclose(transport(cov, predicted, predicted), cov, rtol=1e-12, atol=1e-18)


# ---------------------------------------------------------------------------------------------
# Partial localization: the retry loop


def ring_obs(ids) -> Observations:
    """Everyone observes everyone: any subset of two or more robots stays observable."""
    ids = np.asarray(ids)
    i, j = np.nonzero(~np.eye(len(ids), dtype=bool))
    return Observations(ids[i], ids[j], np.full(len(i), 0.3), np.zeros(len(i)))


def scripted_solver(failures):
    """``solve(mask)``: raises the scripted LocalizationErrors in turn, then returns the mask it got."""
    calls = []

    def solve(keep):
        calls.append(keep.copy())
        if len(calls) <= len(failures):
            raise failures[len(calls) - 1]
        return keep.copy()

    return solve, calls


def test_solver_failures_set_aside_the_robots_they_name():
    """Robots 10..14, everyone observing everyone. The first solve fails
    ('no-convergence' naming 12), the second ('degenerate' naming 14): the third, without 12 and 14, succeeds."""
    ids = np.arange(10, 15)
    solve, calls = scripted_solver([LocalizationError("no-convergence", [12]), LocalizationError("degenerate", [14])])
    keep, result, excluded = solvable_subset(solve, ids, ring_obs(ids))
    assert keep.tolist() == [True, True, False, True, False] and result.tolist() == keep.tolist()
    assert excluded == {12: "no-convergence", 14: "degenerate"}
    assert [c.tolist() for c in calls] == [[True] * 5, [True, True, False, True, True], [True, True, False, True, False]]


def test_at_most_max_retries_solver_failures_are_tolerated():
    """MAX_RETRIES = 3 failures are set aside; a fourth propagates (8 robots, one named each time)."""
    assert MAX_RETRIES == 3
    ids = np.arange(8)
    ok_solve, _ = scripted_solver([LocalizationError("no-convergence", [k]) for k in (1, 2, 3)])
    keep, _, excluded = solvable_subset(ok_solve, ids, ring_obs(ids))
    assert keep.sum() == 5 and set(excluded) == {1, 2, 3}
    failing, calls = scripted_solver([LocalizationError("no-convergence", [k]) for k in (1, 2, 3, 4)])
    with pytest.raises(LocalizationError, match="no-convergence: robots \\[4\\]"):
        solvable_subset(failing, ids, ring_obs(ids))
    assert len(calls) == 4


@pytest.mark.parametrize(
    "error",
    [
        LocalizationError("unobserved", [2]),  # not a solver failure
        LocalizationError("no-convergence", [0, 1, 2, 3]),  # names everybody: nothing left
        LocalizationError("no-convergence", [0, 1, 2]),  # would leave one robot
        LocalizationError("no-convergence", [9]),  # names nobody that is kept
    ],
)
def test_failures_that_cannot_be_set_aside_propagate(error):
    ids = np.arange(4)
    solve, calls = scripted_solver([error])
    with pytest.raises(LocalizationError) as err:
        solvable_subset(solve, ids, ring_obs(ids))
    assert err.value is error and len(calls) == 1


def test_no_retry_propagates_the_first_failure():
    ids = np.arange(4)
    solve, calls = scripted_solver([LocalizationError("no-convergence", [1])])
    with pytest.raises(LocalizationError, match="no-convergence"):
        solvable_subset(solve, ids, ring_obs(ids), retry=False)
    assert len(calls) == 1


def test_unobservable_robots_are_left_out_before_solving():
    """Robots 0..4: 0 -> 1 -> 2 -> 0 is a ring, 3 and 4 see only each other (a second group): {3, 4} is
    disconnected from the largest group, which is solved alone. With one observation 0 -> 1 among three
    robots, fewer than two robots are left after the unobserved are dropped: 'unobserved' is raised."""
    ids = np.arange(5)
    obs = Observations(np.array([0, 1, 2, 3, 4]), np.array([1, 2, 0, 4, 3]), np.full(5, 0.3), np.zeros(5))
    solve, calls = scripted_solver([])
    keep, _, excluded = solvable_subset(solve, ids, obs)
    assert keep.tolist() == [True, True, True, False, False]
    assert excluded == {3: "disconnected", 4: "disconnected"}
    lonely = Observations(np.array([0]), np.array([1]), np.array([0.3]), np.array([0.0]))
    with pytest.raises(LocalizationError, match=r"^unobserved: robots \[0, 1, 2\] \(fewer than two robots can be localized\)$"):
        solvable_subset(solve, np.arange(3), lonely)
    pair = Observations(np.array([0, 1]), np.array([1, 0]), np.full(2, 0.3), np.zeros(2))
    keep, _, excluded = solvable_subset(solve, np.arange(3), pair)  # two robots are enough
    assert keep.tolist() == [True, True, False] and excluded == {2: "unobserved"}


def test_a_set_aside_robot_no_longer_observes_anyone():
    """Robots 0, 1, 2 observe each other; robot 3 is observed only by robot 2. When the solver names robot 2,
    its observations go with it: robot 3 becomes unobserved and is left out too; 0 and 1 are solved."""
    ids = np.arange(4)
    i = np.array([0, 1, 1, 2, 2, 0, 2, 3])
    j = np.array([1, 0, 2, 1, 0, 2, 3, 0])
    obs = Observations(i, j, np.full(8, 0.3), np.zeros(8))
    solve, calls = scripted_solver([LocalizationError("no-convergence", [2])])
    keep, _, excluded = solvable_subset(solve, ids, obs)
    assert keep.tolist() == [True, True, False, False]
    assert excluded == {2: "no-convergence", 3: "unobserved"}


def test_a_failure_may_leave_exactly_two_robots():
    """Three robots observing each other; the solver names robot 2: robots 0 and 1 are solved again."""
    ids = np.arange(3)
    solve, calls = scripted_solver([LocalizationError("degenerate", [2])])
    keep, _, excluded = solvable_subset(solve, ids, ring_obs(ids))
    assert keep.tolist() == [True, True, False] and excluded == {2: "degenerate"} and len(calls) == 2


def test_localize_observable_falls_back_to_dead_reckoning():
    """Nobody observes anybody: every robot keeps dead reckoning, each reported with the reason."""
    ids = np.array([4, 5, 6])
    prior = SwarmEstimate.isotropic(ids, np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0]]), 0.01, 0.01)
    step = StepCommands(ids, np.array([[0.0, 0.1], [0, 0], [0, 0]]), np.array([True, False, False]))
    empty = Observations(np.zeros(0, int), np.zeros(0, int), np.zeros(0), np.zeros(0))
    est, why = localize_observable(JointLocalizer(CFG), prior, step, empty, CFG)
    assert why == {4: "unobserved", 5: "unobserved", 6: "unobserved"}
    dr = dead_reckon(prior, step, CFG, exact=True)  # the joint localizer's: the exact moments of the motion
    np.testing.assert_array_equal(est.poses, dr.poses)
    np.testing.assert_array_equal(est.cov, dr.cov)


# ---------------------------------------------------------------------------------------------
# joint.py helpers


def test_psd_by_hand():
    """diag(1, -1, 2) -> diag(1, 0, 2); a positive definite matrix is returned as it is (symmetrised); a
    NaN matrix is returned as it is; 6x6 matrices use the Cholesky test."""
    out = psd(np.stack([np.diag([1.0, -1.0, 2.0]), np.diag([1.0, 2.0, 3.0]), np.full((3, 3), np.nan)]))
    np.testing.assert_allclose(out[0], np.diag([1.0, 0.0, 2.0]), atol=1e-15)
    np.testing.assert_array_equal(out[1], np.diag([1.0, 2.0, 3.0]))
    assert np.isnan(out[2]).all()
    six = np.diag([1.0, 2.0, -3.0, 4.0, 5.0, 6.0])
    np.testing.assert_allclose(psd(six), np.diag([1.0, 2.0, 0.0, 4.0, 5.0, 6.0]), atol=1e-15)
    p = spd(6, 4)
    np.testing.assert_array_equal(psd(p), 0.5 * (p + p.T))


@pytest.mark.parametrize("diagonal", [(-1.0, -1.0, 1.0), (1.0, -1.0, -1.0), (1.0, 1.0, -1.0)])
def test_psd_checks_every_leading_minor(diagonal):
    """Each diagonal matrix fails exactly one of Sylvester's three minors; its negative entries become 0."""
    np.testing.assert_allclose(psd(np.diag(diagonal)), np.diag(np.maximum(diagonal, 0.0)), atol=1e-15)


def test_psd_symmetrises():
    """An asymmetric positive definite matrix (0.3 above, 0.1 below the diagonal) comes back as its
    symmetric part (0.2 on both sides)."""
    a = np.array([[2.0, 0.3, 0.0], [0.1, 2.0, 0.0], [0.0, 0.0, 1.0]])
    np.testing.assert_allclose(psd(a), [[2.0, 0.2, 0.0], [0.2, 2.0, 0.0], [0.0, 0.0, 1.0]])


def test_psd_joint():
    """Symmetrised as it is when positive definite; projected when not; non-finite returned symmetrised."""
    a = np.array([[2.0, 0.4], [0.0, 1.0]])
    np.testing.assert_array_equal(psd_joint(a), [[2.0, 0.2], [0.2, 1.0]])
    np.testing.assert_allclose(psd_joint(np.diag([1.0, -2.0])), np.diag([1.0, 0.0]), atol=1e-15)
    nan = np.array([[np.nan, 1.0], [0.0, 1.0]])
    out = psd_joint(nan)
    assert np.isnan(out[0, 0]) and out[0, 1] == out[1, 0] == 0.5


def test_block_diagonal_by_hand():
    cov = np.stack([np.full((3, 3), 1.0), np.full((3, 3), 2.0)])
    out = block_diagonal(cov)
    assert out.shape == (6, 6)
    np.testing.assert_array_equal(out[:3, :3], 1.0)
    np.testing.assert_array_equal(out[3:, 3:], 2.0)
    np.testing.assert_array_equal(out[:3, 3:], 0.0)
    np.testing.assert_array_equal(out[3:, :3], 0.0)


def test_worst_observation_names_the_largest_whitened_residual():
    """Prior residuals first (ignored), then (range, bearing) pairs: observation 1 (robots 7 -> 9) has
    3^2 + 1^2 = 10, observation 0 (5 -> 7) 2^2 + 2^2 = 8, so ids 7 and 9 are named; no observation: all."""
    ids = np.array([5, 7, 9])
    residual = np.array([100.0, 100.0, 100.0, 2.0, 2.0, 3.0, -1.0])
    assert worst_observation(residual, np.array([0, 1]), np.array([1, 2]), ids).tolist() == [7, 9]
    assert worst_observation(residual[:3], np.zeros(0, int), np.zeros(0, int), ids).tolist() == [5, 7, 9]


def test_checked_names_robots_with_non_finite_covariances():
    cov = np.stack([np.eye(3), np.full((3, 3), np.nan), np.eye(3), np.diag([1.0, np.inf, 1.0])])
    with pytest.raises(LocalizationError, match=r"degenerate: robots \[11, 13\]"):
        checked(cov, np.array([10, 11, 12, 13]))
    assert checked(cov[[0, 2]], np.array([1, 2])) is not None


def test_pose_covariances_exact_and_conditional(monkeypatch):
    """Information matrix of 2 robots (6x6, correlated), robot 1's heading fixed (5 unknowns). Exact: the
    blocks of the inverse, zero on the fixed heading. Above EXACT_COV_LIMIT: each robot's own information
    block inverted alone (conditional covariance), zero on the fixed heading."""
    layout = PoseLayout(np.ones(2, bool), np.array([True, False]))
    info = np.linalg.inv(spd(5, 11))
    full = np.linalg.inv(info)
    cols = [[0, 1, 2], [3, 4, None]]
    want = np.zeros((2, 3, 3))
    cond = np.zeros((2, 3, 3))
    for r in range(2):
        free = [c for c in cols[r] if c is not None]
        k = len(free)
        want[r, :k, :k] = full[np.ix_(free, free)]
        cond[r, :k, :k] = np.linalg.inv(info[np.ix_(free, free)])
    np.testing.assert_allclose(pose_covariances(info, layout, 2), want, rtol=1e-9, atol=1e-15)
    monkeypatch.setattr(joint_module, "EXACT_COV_LIMIT", 1)
    np.testing.assert_allclose(pose_covariances(info, layout, 2), cond, rtol=1e-9, atol=1e-15)


def four_robots(seed: int):
    ids = np.arange(4)
    poses = np.array([[0.0, 0.0, 0.2], [0.3, 0.0, 1.5], [0.0, 0.3, -2.0], [0.3, 0.3, 3.0]])
    prior = SwarmEstimate.isotropic(ids, poses, 0.02, 0.05)
    obs = sense_swarm(poses, ids, CFG, robot_rngs(seed, ids, Stream.SENSING))
    return prior, StepCommands.stationary(ids), obs


def test_noise_free_joint_localization_keeps_exact_poses():
    """Prior at the truth, noise-free observations of the truth: the solution is the truth, with or
    without the Huber loss and the gauge constraint, and the covariance shrinks below the prior."""
    exact = ModelConfig(range_sigma_m=0.0, bearing_sigma_rad=0.0)
    prior, step, _ = four_robots(0)
    obs = sense_swarm(prior.poses, prior.ids, exact, robot_rngs(0, prior.ids, Stream.SENSING))
    for loc in (JointLocalizer(CFG), JointLocalizer(CFG, huber=1.0), JointLocalizer(CFG, constrain_gauge=False)):
        est = loc.localize(prior, step, obs)
        np.testing.assert_allclose(est.poses[:, :2], prior.poses[:, :2], atol=1e-9)
        np.testing.assert_allclose(wrap_angle(est.poses[:, 2] - prior.poses[:, 2]), 0, atol=1e-9)
        assert (np.trace(est.cov[:, :2, :2], axis1=1, axis2=2) < np.trace(prior.cov[:, :2, :2], axis1=1, axis2=2)).all()


def test_huber_changes_the_answer_only_with_outliers():
    """An observation range off by 0.1 m (10 sigmas): least squares follows it partly, Huber (1 sigma) much
    less; on clean data both agree to the solver's tolerance."""
    prior, step, obs = four_robots(1)
    plain, robust = JointLocalizer(CFG), JointLocalizer(CFG, huber=1.0)
    a, b = plain.localize(prior, step, obs), robust.localize(prior, step, obs)
    assert np.abs(a.poses - b.poses).max() < 0.01
    bad = Observations(obs.observer, obs.observed, obs.range_m + np.where(np.arange(len(obs.range_m)) == 0, 0.1, 0.0), obs.bearing_rad)
    a, b = plain.localize(prior, step, bad), robust.localize(prior, step, bad)
    i, j = obs.observer[0], obs.observed[0]
    stretch_a = np.hypot(*(a.poses[j, :2] - a.poses[i, :2])) - np.hypot(*(prior.poses[j, :2] - prior.poses[i, :2]))
    stretch_b = np.hypot(*(b.poses[j, :2] - b.poses[i, :2])) - np.hypot(*(prior.poses[j, :2] - prior.poses[i, :2]))
    assert stretch_a > 2 * stretch_b


def test_conditional_covariances_above_the_exact_limit(monkeypatch):
    """Above EXACT_COV_LIMIT no joint covariance is returned, and so no observability-constrained correction of
    the poses (``gauge.constrained_solution`` needs it): they are the least-squares solution, as without the
    constraint, within micrometres of the constrained poses below the limit."""
    prior, step, obs = four_robots(2)
    exact = JointLocalizer(CFG).localize(prior, step, obs)
    plain = JointLocalizer(CFG, constrain_gauge=False).localize(prior, step, obs)
    monkeypatch.setattr(joint_module, "EXACT_COV_LIMIT", 3)
    blocks = JointLocalizer(CFG).localize(prior, step, obs)
    assert exact.joint is not None and blocks.joint is None
    np.testing.assert_allclose(blocks.poses, plain.poses, atol=1e-12)
    np.testing.assert_allclose(blocks.poses, exact.poses, atol=1e-4)
    assert (np.abs(blocks.poses[:, 2]) <= np.pi).all()
    # Conditional covariances are optimistic: never above the exact marginals.
    assert (np.linalg.eigvalsh(exact.cov - blocks.cov) > -1e-15).all()


def test_worst_observation_accepts_per_observation_rows():
    """The (m, 2) residuals of ``JointProblem.residuals``: the same choice as the flat vector."""
    rows = np.array([[2.0, 2.0], [3.0, -1.0]])
    assert worst_observation(rows, np.array([0, 1]), np.array([1, 2]), np.array([5, 7, 9])).tolist() == [7, 9]


def test_localize_subset_updates_the_kept_robots_only():
    """Robots 0-3 kept (they observe each other), robot 4 set aside. Robot 4 keeps its dead reckoning
    (pose and covariance). Without the gauge constraint the joint covariance is merge_subset's linear
    update: P_A'B = P_AA' P_AA^-1 P_AB and P_BB unchanged (P = the dead-reckoned joint prior); with a
    first-step prior (independent robots, no joint) the cross-covariances stay 0."""
    ids = np.arange(5)
    poses = np.array([[0.0, 0.0, 0.2], [0.3, 0.0, 1.5], [0.0, 0.3, -2.0], [0.3, 0.3, 3.0], [2.0, 2.0, 0.0]])
    keep = np.array([True, True, True, True, False])
    step = StepCommands(ids, np.array([[0.0, 0.05]] * 5), np.array([True, False, False, False, True]))
    obs = sense_swarm(poses, ids, CFG, robot_rngs(4, ids, Stream.SENSING))
    joint_prior = SwarmEstimate.from_joint(ids, poses, spd(15, 12, 0.005))
    loc = JointLocalizer(CFG, constrain_gauge=False)
    est = loc.localize_subset(joint_prior, step, obs, keep)
    dr = dead_reckon(joint_prior, step, CFG, exact=True)
    np.testing.assert_array_equal(est.poses[4], dr.poses[4])
    a, b = np.arange(12), np.arange(12, 15)
    np.testing.assert_allclose(est.joint[np.ix_(b, b)], dr.joint[np.ix_(b, b)], rtol=1e-12)
    want_ab = est.joint[np.ix_(a, a)] @ np.linalg.solve(dr.joint[np.ix_(a, a)], dr.joint[np.ix_(a, b)])
    np.testing.assert_allclose(est.joint[np.ix_(a, b)], want_ab, rtol=1e-6, atol=1e-15)
    assert np.abs(est.poses[:4] - dr.poses[:4]).max() > 0
    first = loc.localize_subset(SwarmEstimate(ids, poses, joint_prior.cov), step, obs, keep)
    np.testing.assert_array_equal(first.joint[np.ix_(a, b)], 0.0)
    np.testing.assert_allclose(first.cov[4], dr.cov[4], rtol=1e-12)
    assert first.joint.shape == (15, 15)


def test_joint_topology_of_exact_observations():
    """Noise-free observations of four robots: the topology is the swarm seen from its reference robot
    (robot 0, the lowest that observed someone): positions R(-theta_0) (p - p_0), headings theta - theta_0;
    the reference itself has no uncertainty."""
    exact = ModelConfig(range_sigma_m=0.0, bearing_sigma_rad=0.0)
    ids = np.arange(10, 14)
    poses = np.array([[0.1, 0.2, 0.7], [0.4, 0.2, 1.5], [0.1, 0.5, -2.0], [0.4, 0.5, 3.0]])
    obs = sense_swarm(poses, ids, exact, robot_rngs(0, ids, Stream.SENSING))
    topo = JointLocalizer(CFG).topology(ids, obs)
    c, s = math.cos(-0.7), math.sin(-0.7)
    rel = (poses[:, :2] - poses[0, :2]) @ np.array([[c, s], [-s, c]])
    assert topo.reference == 0
    np.testing.assert_allclose(topo.solved_positions, rel, atol=1e-9)
    np.testing.assert_allclose(topo.positions, rel, atol=1e-9)
    np.testing.assert_allclose(wrap_angle(topo.headings - (poses[:, 2] - 0.7)), 0, atol=1e-9)
    assert topo.delta_p[0] == 0 and (topo.delta_p[1:] > 0).all() and np.isfinite(topo.heading_sigma).all()


def test_psd_of_rotated_matrices_with_known_eigenvalues():
    """V diag(lambda) V^T for random rotations V: with one negative eigenvalue psd gives V diag(max(lambda,
    0)) V^T; positive definite ones come back exactly as they are (the cheap 3x3 test must not send them
    to the eigen-decomposition). Off-diagonal entries exercise every term of the determinant."""
    rng = np.random.default_rng(21)
    for _ in range(60):
        v, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        lam = rng.uniform(0.1, 2.0, 3)
        pd = v @ np.diag(lam) @ v.T
        pd = 0.5 * (pd + pd.T)
        np.testing.assert_array_equal(psd(pd), pd)
        lam[rng.integers(3)] *= -1
        bad = v @ np.diag(lam) @ v.T
        np.testing.assert_allclose(psd(bad), v @ np.diag(np.maximum(lam, 0)) @ v.T, atol=1e-12)


def test_pose_covariances_of_a_singular_information_are_nan():
    """A zero information matrix has no inverse: every covariance is NaN (``checked`` then names the robots)."""
    out = pose_covariances(np.zeros((6, 6)), PoseLayout(np.ones(2, bool), np.ones(2, bool)), 2)
    assert out.shape == (2, 3, 3) and np.isnan(out).all()


def test_gauge_frame_projector_in_closed_form():
    """About the centroid, N^T N = diag(n, n, n + sum |c_i|^2): for poses (0, 0), (2, 0), (1, 3) the centroid is
    (1, 1), offsets (-1, -1), (1, -1), (0, 2), so N^T N = diag(3, 3, 3 + 2 + 2 + 4) = diag(3, 3, 11) and the
    projector is N^T scaled row by row by 1/3, 1/3, 1/11; it maps N onto the identity."""
    from coordinator.localization.gauge import gauge_frame

    poses = np.array([[0.0, 0.0, 0.3], [2.0, 0.0, -1.0], [1.0, 3.0, 2.0]])
    basis, proj = gauge_frame(poses)
    np.testing.assert_array_equal(basis, gauge_basis(poses))
    np.testing.assert_allclose(proj, basis.T / np.array([[3.0], [3.0], [11.0]]), rtol=1e-15)
    np.testing.assert_allclose(proj @ basis, np.eye(3), atol=1e-15)


def test_conditional_pose_covariances_of_sparse_and_singular_information(monkeypatch):
    """Above EXACT_COV_LIMIT the blocks are read from a sparse information matrix as from a dense one (a
    1000-robot step's is sparse); a zero information matrix has singular blocks: every covariance NaN."""
    monkeypatch.setattr(joint_module, "EXACT_COV_LIMIT", 1)
    layout = PoseLayout(np.ones(2, bool), np.array([True, False]))
    info = np.linalg.inv(spd(5, 11))
    want = np.zeros((2, 3, 3))
    want[0] = np.linalg.inv(info[:3, :3])
    want[1, :2, :2] = np.linalg.inv(info[3:, 3:])
    np.testing.assert_allclose(pose_covariances(sp.csr_matrix(info), layout, 2), want, rtol=1e-9, atol=1e-15)
    out = pose_covariances(np.zeros((5, 5)), layout, 2)
    assert out.shape == (2, 3, 3) and np.isnan(out[0]).all() and np.isnan(out[1, :2, :2]).all()


def outlier_case():
    """Four robots (ids 20-23) observing each other, observation 0's range 0.3 m (30 sigma) too long: after
    one iteration its whitened residual is still by far the largest."""
    ids = np.arange(20, 24)
    poses = np.array([[0.0, 0.0, 0.2], [0.3, 0.0, 1.5], [0.0, 0.3, -2.0], [0.3, 0.3, 3.0]])
    prior = SwarmEstimate.isotropic(ids, poses, 0.02, 0.05)
    obs = sense_swarm(poses, ids, CFG, robot_rngs(3, ids, Stream.SENSING))
    bad = Observations(obs.observer, obs.observed, obs.range_m + np.where(np.arange(len(obs.range_m)) == 0, 0.3, 0.0),
                       obs.bearing_rad)
    return prior, StepCommands.stationary(ids), bad, sorted([int(obs.observer[0]), int(obs.observed[0])])


def test_no_convergence_names_the_robots_of_the_worst_observation(monkeypatch):
    """Solvers allowed a single iteration (and no convergence test) do not converge: the joint solve raises
    'no-convergence' naming the two robots of the outlier observation, and so does the joint topology."""
    prior, step, obs, pair = outlier_case()
    real_min, real_lm = joint_module.minimize, joint_module.levenberg_marquardt
    monkeypatch.setattr(joint_module, "minimize", lambda *a, **kw: real_min(*a, **{**kw, "max_iter": 1, "xtol": 0.0, "ftol": 0.0}))
    with pytest.raises(LocalizationError) as err:
        JointLocalizer(CFG).localize(prior, step, obs)
    assert err.value.reason == "no-convergence" and err.value.robots == pair
    assert str(err.value) == f"no-convergence: robots {pair} (joint least squares did not converge)"
    monkeypatch.setattr(joint_module, "levenberg_marquardt", lambda *a, **kw: real_lm(*a, **{**kw, "max_iter": 1, "xtol": 0.0, "ftol": 0.0}))
    with pytest.raises(LocalizationError) as err:
        JointLocalizer(CFG).topology(prior.ids, obs)
    assert str(err.value) == f"no-convergence: robots {pair} (joint topology did not converge)"


def test_a_singular_information_matrix_names_its_robots(monkeypatch):
    """If the inverse of the information matrix is NaN on robot 22's rows and columns (singular for it), the
    joint solve raises 'degenerate' naming robot 22 only (the other robots' diagonal blocks are finite)."""
    prior, step, obs, _ = outlier_case()
    real = joint_module.inverse

    def singular_for_robot_2(normal):
        out = np.array(real(normal), dtype=float)
        out[6:9, :] = out[:, 6:9] = np.nan
        return out

    monkeypatch.setattr(joint_module, "inverse", singular_for_robot_2)
    with pytest.raises(LocalizationError) as err:
        JointLocalizer(CFG, constrain_gauge=False).localize(prior, step, obs)
    assert str(err.value) == "degenerate: robots [22] (the information matrix is singular for them)"


def test_exactly_exact_cov_limit_robots_get_the_joint_covariance(monkeypatch):
    """Up to and including EXACT_COV_LIMIT robots the joint covariance is returned: four robots at a limit of 4
    give the same estimate as at the default limit."""
    prior, step, obs = four_robots(2)
    want = JointLocalizer(CFG).localize(prior, step, obs)
    monkeypatch.setattr(joint_module, "EXACT_COV_LIMIT", 4)
    got = JointLocalizer(CFG).localize(prior, step, obs)
    assert got.joint is not None
    np.testing.assert_array_equal(got.joint, want.joint)


def test_localize_subset_takes_any_truth_values_as_keep():
    """``keep`` as a list of 0/1 integers selects the same robots as the boolean mask."""
    prior, step, obs = four_robots(4)
    loc = JointLocalizer(CFG)
    want = loc.localize_subset(prior, step, obs, np.array([True, True, True, False]))
    got = loc.localize_subset(prior, step, obs, [1, 1, 1, 0])
    np.testing.assert_array_equal(got.poses, want.poses)
    np.testing.assert_array_equal(got.cov, want.cov)


def test_joint_topology_uncertainties_are_those_of_the_information_matrix(monkeypatch):
    """delta_p = sqrt(var x + var y) and the heading sigma sqrt(var theta) from the inverse of J^T J at the
    solution (its free unknowns: all but the reference robot's pose); the reference robot gets 0 and 0."""
    prior, _, obs = four_robots(5)
    results, real = [], joint_module.levenberg_marquardt

    def spy(*a, **kw):
        results.append(real(*a, **kw))
        return results[-1]

    monkeypatch.setattr(joint_module, "levenberg_marquardt", spy)
    topo = JointLocalizer(CFG).topology(prior.ids, obs)
    assert topo.reference == 0
    cov = np.linalg.inv(np.asarray(results[0].normal_matrix.toarray() if sp.issparse(results[0].normal_matrix)
                                   else results[0].normal_matrix))  # unknowns (x, y, theta) of robots 1, 2, 3
    var = np.diag(cov).reshape(3, 3)
    np.testing.assert_allclose(topo.delta_p, np.r_[0.0, np.sqrt(var[:, 0] + var[:, 1])], rtol=1e-9)
    np.testing.assert_allclose(topo.heading_sigma, np.r_[0.0, np.sqrt(var[:, 2])], rtol=1e-9)


def test_the_gauge_constraint_is_on_by_default():
    """``JointLocalizer(cfg)`` returns the observability-constrained update (constrain_gauge=True): its
    covariance differs from the unconstrained (J^T J)^-1, its poses from the least-squares ones by the
    constrained step (``gauge.constrained_solution``: small, well under a millimetre here)."""
    prior, step, obs = four_robots(6)
    default = JointLocalizer(CFG).localize(prior, step, obs)
    on = JointLocalizer(CFG, constrain_gauge=True).localize(prior, step, obs)
    off = JointLocalizer(CFG, constrain_gauge=False).localize(prior, step, obs)
    np.testing.assert_array_equal(default.joint, on.joint)
    np.testing.assert_array_equal(default.poses, on.poses)
    assert 0 < np.abs(off.poses - on.poses).max() < 1e-3
    assert np.abs(off.joint - on.joint).max() > 1e-3 * np.abs(on.joint).max()


def test_psd_clips_a_matrix_whose_determinant_alone_reveals_it():
    """M = [[1, t, t], [t, 1, -t], [t, -t, 1]], t = 0.55: both leading minors are positive (1, 0.6975) but
    det M = 1 - 3 t^2 - 2 t^3 = -0.24 < 0 (every term of the determinant matters: dropping the sign of one
    would call M positive definite). v = (1, -1, -1)/sqrt(3) has
    M v = (1 - 2t) v = -0.1 v; the other eigenvalue is 1 + t = 1.55 (twice). psd(M) = M + 0.1 v v^T."""
    t = 0.55
    m = np.array([[1, t, t], [t, 1, -t], [t, -t, 1.0]])
    v = np.array([1.0, -1.0, -1.0]) / math.sqrt(3)
    np.testing.assert_allclose(m @ v, -0.1 * v, atol=1e-15)
    np.testing.assert_allclose(psd(m), m + 0.1 * np.outer(v, v), atol=1e-12)


def test_pose_covariances_at_exactly_the_limit_are_exact(monkeypatch):
    """n_robots == EXACT_COV_LIMIT still gets the exact blocks of the inverse (not the conditional ones)."""
    layout = PoseLayout(np.ones(2, bool), np.ones(2, bool))
    info = np.linalg.inv(spd(6, 13))
    monkeypatch.setattr(joint_module, "EXACT_COV_LIMIT", 2)
    full = np.linalg.inv(info)
    want = np.stack([full[:3, :3], full[3:, 3:]])
    np.testing.assert_allclose(pose_covariances(info, layout, 2), want, rtol=1e-9, atol=1e-15)


def test_worst_observation_compares_squares_not_signed_values():
    """Residual rows (-3, 0) and (2, 1): squares 9 and 5, so the first observation (robots 5 -> 7) is the worst,
    though its residual is negative."""
    rows = np.array([[-3.0, 0.0], [2.0, 1.0]])
    assert worst_observation(rows, np.array([0, 1]), np.array([1, 2]), np.array([5, 7, 9])).tolist() == [5, 7]


def nan_for_robot(k: int, real):
    """Wrap ``real`` (returning (n, 3, 3) blocks or a (3n, 3n) joint covariance) to make robot k's entries NaN."""
    def wrapped(*args, **kwargs):
        out = np.array(real(*args, **kwargs), dtype=float)
        if out.ndim == 3:
            out[k] = np.nan
        else:
            out[3 * k : 3 * k + 3, :] = out[:, 3 * k : 3 * k + 3] = np.nan
        return out
    return wrapped


def test_non_finite_covariances_are_named_on_every_path(monkeypatch):
    """Whichever path yields the covariances, a non-finite block for robot 2 (id 22) raises 'degenerate'
    naming it: the conditional blocks above EXACT_COV_LIMIT, the joint topology's blocks, and the final
    joint covariance of ``localize_subset`` (after the gauge transport)."""
    prior, step, obs, _ = outlier_case()
    want = "degenerate: robots [22] (the information matrix is singular for them)"
    with monkeypatch.context() as m:
        m.setattr(joint_module, "EXACT_COV_LIMIT", 3)
        m.setattr(joint_module, "pose_covariances", nan_for_robot(2, joint_module.pose_covariances))
        with pytest.raises(LocalizationError) as err:
            JointLocalizer(CFG).localize(prior, step, obs)
        assert str(err.value) == want
    with monkeypatch.context() as m:
        m.setattr(joint_module, "pose_covariances", nan_for_robot(2, joint_module.pose_covariances))
        with pytest.raises(LocalizationError) as err:
            JointLocalizer(CFG).topology(prior.ids, obs)
        assert str(err.value) == want
    with monkeypatch.context() as m:
        m.setattr(joint_module, "psd_joint", nan_for_robot(2, joint_module.psd_joint))
        with pytest.raises(LocalizationError) as err:
            JointLocalizer(CFG).localize(prior, step, obs)
        assert str(err.value) == want


def test_joint_topology_of_a_robot_that_observed_nobody():
    """Robot 3 (id 13) observes nobody (others observe it): its position is solved, its heading is unknown
    (NaN, sigma inf); the others' positions and headings are those of the swarm seen from robot 0."""
    exact = ModelConfig(range_sigma_m=0.0, bearing_sigma_rad=0.0)
    ids = np.arange(10, 14)
    poses = np.array([[0.1, 0.2, 0.7], [0.4, 0.2, 1.5], [0.1, 0.5, -2.0], [0.4, 0.5, 3.0]])
    obs = sense_swarm(poses, ids, exact, robot_rngs(0, ids, Stream.SENSING))
    obs = obs.select(obs.observer != 13)
    topo = JointLocalizer(CFG).topology(ids, obs)
    c, s = math.cos(-0.7), math.sin(-0.7)
    rel = (poses[:, :2] - poses[0, :2]) @ np.array([[c, s], [-s, c]])
    np.testing.assert_allclose(topo.positions, rel, atol=1e-9)
    assert np.isnan(topo.headings[3]) and topo.heading_sigma[3] == np.inf
    np.testing.assert_allclose(wrap_angle(topo.headings[:3] - (poses[:3, 2] - 0.7)), 0, atol=1e-9)


def test_joint_topology_uses_the_huber_loss():
    """With a 0.3 m (30 sigma) range outlier the Huber topology (1 sigma) keeps the outlier pair's distance
    much closer to the truth than least squares does."""
    prior, _, obs, pair = outlier_case()
    truth = np.hypot(*(prior.poses[pair[1] - 20, :2] - prior.poses[pair[0] - 20, :2]))
    stretch = []
    for loc in (JointLocalizer(CFG), JointLocalizer(CFG, huber=1.0)):
        topo = loc.topology(prior.ids, obs)
        stretch.append(abs(np.hypot(*(topo.positions[pair[1] - 20] - topo.positions[pair[0] - 20])) - truth))
    assert stretch[0] > 3 * stretch[1]


@pytest.mark.parametrize(
    "m",
    [
        [[4.0, 2.5, 0.0], [2.5, 1.0, 0.0], [0.0, 0.0, -1.0]],
        [[1.0, 0.6, 0.0], [0.6, 0.25, 0.0], [0.0, 0.0, -1.0]],
    ],
)
def test_psd_clips_two_negative_eigenvalues_that_only_the_second_minor_reveals(m):
    """First leading minor positive, determinant positive (-1 x (a b - d^2) > 0), but the second minor
    a b - d^2 is negative (4 - 6.25, 0.25 - 0.36): two negative eigenvalues. psd sets both to zero:
    V diag(max(lambda, 0)) V^T."""
    m = np.array(m)
    lam, vec = np.linalg.eigh(m)
    assert (lam < 0).sum() == 2 and np.linalg.det(m) > 0
    np.testing.assert_allclose(psd(m), (vec * np.maximum(lam, 0.0)) @ vec.T, atol=1e-12)
