"""Joint covariance bookkeeping (SwarmEstimate.joint) and the NEES consistency study."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from coordinator.consistency import chi2_band, position_nees
from coordinator.localization import make_localizer
from coordinator.localization.dead_reckoning import dead_reckon, propagate_joint
from coordinator.localization.gauge import (
    constrained_solution,
    gauge_basis,
    gauge_frame,
    merge_subset,
    transport,
    transport_offset,
    transported_blocks,
)
from coordinator.localization.joint import JointLocalizer
from inchworm.noise import scaled
from runtime.errors import SwarmInputError
from runtime.models.config import ModelConfig
from runtime.models.geometry import wrap_angle
from runtime.models.motion import apply_motion, draw_motion_noise, motion_covariance, motion_moments
from runtime.models.rng import Stream, robot_rngs
from runtime.models.scenarios import random_step
from runtime.models.sensing import sense_swarm
from runtime.models.state import StepCommands, SwarmEstimate

CFG = ModelConfig()


def random_joint(n: int, seed: int) -> np.ndarray:
    a = np.random.default_rng(seed).normal(size=(3 * n, 3 * n)) * 0.01
    return a @ a.T + 1e-4 * np.eye(3 * n)


def test_select_marginalises_the_joint_covariance():
    joint = random_joint(4, 0)
    est = SwarmEstimate.from_joint([10, 11, 12, 13], np.zeros((4, 3)), joint)
    np.testing.assert_array_equal(est.cov[2], joint[6:9, 6:9])
    sub = est.select(np.array([True, False, True, False]))
    np.testing.assert_array_equal(sub.joint, joint[np.r_[0:3, 6:9]][:, np.r_[0:3, 6:9]])
    np.testing.assert_array_equal(sub.cov, est.cov[[0, 2]])
    assert est.select(np.array([False, True, True, True])).select(np.array([True, False, True])).joint.shape == (6, 6)
    plain = SwarmEstimate.isotropic([1, 2], np.zeros((2, 3)), 0.01, 0.01)
    assert plain.joint is None and plain.select(np.array([True, False])).joint is None
    with pytest.raises(SwarmInputError, match="joint covariance must have shape"):
        SwarmEstimate([1, 2], np.zeros((2, 3)), plain.cov, np.eye(3))


@pytest.mark.parametrize("exact", [False, True])
def test_dead_reckoning_propagates_the_joint_covariance_consistently_with_the_marginals(exact):
    case = random_step(6, CFG, np.random.default_rng(1))
    joint = random_joint(6, 1)
    prior = SwarmEstimate.from_joint(case.prior.ids, case.prior.poses, joint)
    dr = dead_reckon(prior, case.step, CFG, exact)
    marginal = dead_reckon(SwarmEstimate(prior.ids, prior.poses, prior.cov), case.step, CFG, exact)
    np.testing.assert_allclose(dr.cov, marginal.cov, rtol=1e-12, atol=1e-18)
    np.testing.assert_array_equal(dr.poses, marginal.poses)
    still = ~case.step.moving
    idx = (3 * np.flatnonzero(still))[:, None] + np.arange(3)
    np.testing.assert_allclose(dr.joint[idx.ravel()][:, idx.ravel()], joint[idx.ravel()][:, idx.ravel()])  # anchors untouched


def test_joint_localizer_carries_the_joint_covariance():
    case = random_step(8, CFG, np.random.default_rng(2))
    loc = make_localizer("joint", CFG)
    first = loc.localize(case.prior, case.step, case.observations)
    assert first.joint is not None
    np.testing.assert_allclose(first.cov, SwarmEstimate.from_joint(first.ids, first.poses, first.joint).cov)
    # A joint prior that is block-diagonal is the same information as the per-robot marginals.
    blocky = SwarmEstimate.from_joint(case.prior.ids, case.prior.poses, _block(case.prior.cov))
    again = loc.localize(blocky, case.step, case.observations)
    np.testing.assert_allclose(again.poses, first.poses, atol=1e-9)
    np.testing.assert_allclose(again.joint, first.joint, rtol=1e-6, atol=1e-15)
    # Correlations change the answer: the second step's prior holds them.
    step2 = loc.localize(first, case.step, case.observations)
    independent = loc.localize(SwarmEstimate(first.ids, first.poses, first.cov), case.step, case.observations)
    assert step2.joint is not None and not np.allclose(step2.cov, independent.cov, rtol=1e-3)


def _gauge_information(est: SwarmEstimate, center: np.ndarray) -> np.ndarray:
    basis = gauge_basis(est.poses, center)
    return basis.T @ np.linalg.solve(est.joint, basis)


@pytest.mark.parametrize("seed", [2, 3, 4])
def test_constrained_update_gains_no_information_on_the_global_pose(seed):
    """Observations are blind to the swarm's global translation and rotation, so an update may not
    add information along them (Huang, Mourikis & Roumeliotis 2010). The plain inverse of J^T J does
    (its Jacobian is blind at the solution, not at the prediction): that made long runs overconfident."""
    case = random_step(8, CFG, np.random.default_rng(seed))
    first = make_localizer("joint", CFG).localize(case.prior, case.step, case.observations)
    still = StepCommands.stationary(first.ids)  # then a second look from where they stand
    again = sense_swarm(case.true_after, first.ids, CFG, robot_rngs(seed + 100, first.ids, Stream.SENSING))
    predicted = dead_reckon(first, still, CFG)
    center = predicted.positions.mean(axis=0)  # the same fixed point before and after (gauge.transport)
    before = _gauge_information(predicted, center)
    gained = {}
    for constrained in (True, False):
        post = JointLocalizer(CFG, constrain_gauge=constrained).localize(first, still, again)
        gained[constrained] = np.linalg.eigvalsh(_gauge_information(post, center) - before).max() / np.abs(before).max()
    assert gained[True] < 1e-8
    assert gained[False] > 1e-5


def test_constrained_solution_of_one_robot_is_the_prediction():
    """Known answer, by hand: for one robot every direction is gauge (N = I: translation, and rotation about its
    own position), so H~ = 0, the constrained covariance is the prior P and the update must return the
    prediction mu whatever the least-squares solution x*: x* - P Pi^T N^T P^-1 (x* - mu) = mu."""
    mu = np.array([[0.3, -0.2, 1.0]])
    x = mu + np.array([[0.01, 0.02, -0.03]])
    p = random_joint(1, 8)
    np.testing.assert_allclose(constrained_solution(x, mu, p, np.linalg.solve(p, (x - mu).ravel())), mu, atol=1e-15)


def test_constrained_solution_is_a_newton_step_to_the_constrained_fixed_point():
    """Linear known answer: with z = H e + v and H = H0 + eps E (H0 blind to the gauge N(mu), eps E the spurious
    part), the least-squares update x* solves (P^-1 + H^T H) e = H^T z; the observability-constrained one solves
    P^-1 e = H~^T (z - H e), H~ = H (I - N Pi). One step from x* lands within O(eps^2) of it (x* is O(eps) away),
    and its prior-weighted update has no component along the gauge, N^T P^-1 e = 0 (as H~ N = 0)."""
    rng = np.random.default_rng(3)
    mu = np.column_stack([rng.uniform(-1, 1, (3, 2)), rng.uniform(-3, 3, 3)])
    p = random_joint(3, 3)
    info = np.linalg.inv(p)
    basis = gauge_basis(mu)
    off = np.eye(9) - basis @ np.linalg.pinv(basis)
    h0, spurious, z = 10 * rng.normal(size=(8, 9)) @ off, 10 * rng.normal(size=(8, 9)), rng.normal(size=8)
    gaps = []
    for eps in (1e-2, 1e-3):
        h = h0 + eps * spurious
        h_c = h @ off
        plain = np.linalg.solve(info + h.T @ h, h.T @ z)
        want = np.linalg.solve(info + h_c.T @ h, h_c.T @ z)
        cov = np.linalg.inv(info + h_c.T @ h_c)
        got = constrained_solution(mu + plain.reshape(3, 3), mu, cov, info @ plain).ravel() - mu.ravel()
        np.testing.assert_allclose(basis.T @ info @ got, 0, atol=1e-10)
        gaps.append((np.abs(got - want).max(), np.abs(plain - want).max()))
    assert gaps[0][1] / gaps[1][1] == pytest.approx(10, rel=0.05)  # the least-squares update: O(eps) off
    assert gaps[0][0] / gaps[1][0] == pytest.approx(100, rel=0.05)  # the constrained step: O(eps^2)
    assert gaps[1][0] < 1e-3 * gaps[1][1]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_constrained_update_takes_no_step_along_the_gauge_on_its_own(seed):
    """The estimate, not only the covariance: a consistent update's step, weighted by the prior information,
    has no component along the predicted gauge (N^T P^-1 (x - mu) = 0, Huang et al. 2010). The plain least-squares
    solution has one (its Jacobian is blind at the solution, not at the prediction): each update then turned the
    swarm's estimated global pose by noise no covariance accounted for, and along 100 configurations the heading
    error grew to 2-6 x its reported variance. Prior: the large, far-levered gauge uncertainty of a long run."""
    rng = np.random.default_rng(seed)
    case = random_step(8, CFG, rng)
    mean = case.prior.poses
    far = gauge_basis(mean, mean[:, :2].mean(axis=0) + np.array([1.5, 0.0]))
    joint = 0.01**2 * np.eye(24) + far @ np.diag([0.05**2, 0.05**2, 0.08**2]) @ far.T
    prior = SwarmEstimate.from_joint(case.prior.ids, mean, joint)
    truth = mean + (np.linalg.cholesky(joint) @ rng.normal(size=24)).reshape(8, 3)
    obs = sense_swarm(truth, prior.ids, CFG, robot_rngs(seed, prior.ids, Stream.SENSING))
    basis = gauge_basis(mean)
    along = {}
    for constrained in (True, False):
        est = JointLocalizer(CFG, constrain_gauge=constrained).localize(prior, StepCommands.stationary(prior.ids), obs)
        step = est.poses - mean
        step[:, 2] = wrap_angle(step[:, 2])
        along[constrained] = np.abs(basis.T @ np.linalg.solve(joint, step.ravel())).max()
    assert along[False] > 1e-4
    assert along[True] < 1e-8 * along[False]


def test_merge_subset_is_the_linear_update_of_the_kept_robots():
    """Known answer: a linear measurement z = H x_A + v (v ~ N(0, I)) of robots A only, the Kalman update
    of A, B left as they are. Errors: e_A' = (I - K H) e_A - K v, e_B' = e_B, so
    Cov = [[C_A, (I - K H) P_AB], [P_BA (I - K H)^T, P_BB]] with C_A = (P_AA^-1 + H^T H)^-1, K = C_A H^T."""
    rng = np.random.default_rng(5)
    prior = random_joint(4, 5)
    keep = np.array([True, False, True, True])
    a = np.r_[0:3, 6:12]
    b = np.r_[3:6]
    h = rng.normal(size=(7, 9))
    c_a = np.linalg.inv(np.linalg.inv(prior[np.ix_(a, a)]) + h.T @ h)
    gain = c_a @ h.T
    want_ab = (np.eye(9) - gain @ h) @ prior[np.ix_(a, b)]
    got = merge_subset(prior, c_a, keep)
    np.testing.assert_allclose(got[np.ix_(a, a)], c_a, rtol=1e-12)
    np.testing.assert_allclose(got[np.ix_(a, b)], want_ab, rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(got[np.ix_(b, b)], prior[np.ix_(b, b)])
    np.testing.assert_allclose(got, got.T)
    assert np.linalg.eigvalsh(got).min() > 0
    np.testing.assert_array_equal(merge_subset(prior, c_a, np.ones(3, bool)), c_a)


def test_merge_subset_takes_a_pose_known_exactly():
    """A kept robot with zero prior variance (the planner's known start): the same linear update, in its
    covariance form C_A = P_AA - K H P_AA, K = P_AA H^T (H P_AA H^T + I)^-1, and no error is raised."""
    rng = np.random.default_rng(7)
    prior = random_joint(4, 8)
    prior[0:3, :] = 0.0
    prior[:, 0:3] = 0.0  # robot 0 known exactly: no variance, no correlation
    keep = np.array([True, False, True, True])
    a, b = np.r_[0:3, 6:12], np.r_[3:6]
    h = rng.normal(size=(7, 9))
    p_aa = prior[np.ix_(a, a)]
    gain = p_aa @ h.T @ np.linalg.inv(h @ p_aa @ h.T + np.eye(7))
    c_a = p_aa - gain @ h @ p_aa
    got = merge_subset(prior, c_a, keep)
    assert np.isfinite(got).all()
    np.testing.assert_allclose(got[np.ix_(a, b)], (np.eye(9) - gain @ h) @ prior[np.ix_(a, b)], rtol=1e-7, atol=1e-12)
    np.testing.assert_allclose(got[np.ix_(b, b)], prior[np.ix_(b, b)])
    np.testing.assert_allclose(got[0:3], 0.0, atol=1e-12)


def test_transport_is_the_rank_three_map_of_the_gauge():
    rng = np.random.default_rng(6)
    predicted = np.column_stack([rng.uniform(-1, 1, (5, 2)), rng.uniform(-3, 3, 5)])
    solution = predicted + rng.normal(0, 0.02, (5, 3))
    cov = random_joint(5, 6)
    center = predicted[:, :2].mean(axis=0)
    basis = gauge_basis(predicted, center)
    t = np.eye(15) + (gauge_basis(solution, center) - basis) @ np.linalg.pinv(basis)
    np.testing.assert_allclose(t @ basis, gauge_basis(solution, center), atol=1e-12)
    np.testing.assert_allclose(transport(cov, predicted, solution), t @ cov @ t.T, rtol=1e-10, atol=1e-16)
    # The gauge: a global translation and a rotation about the centroid, with heading rate 1.
    g = gauge_basis(predicted).reshape(5, 3, 3)
    np.testing.assert_array_equal(g[:, :, 0], np.tile([1.0, 0.0, 0.0], (5, 1)))
    np.testing.assert_allclose(g[:, :2, 2], np.column_stack([-(predicted[:, 1] - predicted[:, 1].mean()), predicted[:, 0] - predicted[:, 0].mean()]))
    np.testing.assert_array_equal(g[:, 2, 2], np.ones(5))


def test_gauge_functions_take_a_batch_axis_and_a_subset():
    """Batched (two swarms stacked), ``gauge_frame`` and ``transport`` equal the single-swarm calls swarm by swarm;
    ``transported_blocks`` (from the blocks, Pi C and Pi C Pi^T) equals the 3x3 diagonal blocks of ``transport``;
    ``gauge_frame(keep)`` is the kept robots' own frame (rotation about their centroid, Pi = (N^T N)^-1 N^T) with
    zero rows / columns for the others."""
    rng = np.random.default_rng(11)
    predicted = np.stack([np.column_stack([rng.uniform(-1, 1, (5, 2)), rng.uniform(-3, 3, 5)]) for _ in range(2)])
    solution = predicted + rng.normal(0, 0.02, predicted.shape)
    cov = np.stack([random_joint(5, 7), random_joint(5, 8)])
    basis, proj = gauge_frame(predicted)
    moved = transport(cov, predicted, solution, (basis, proj))
    idx = np.arange(15).reshape(5, 3)
    for k in range(2):
        one_basis, one_proj = gauge_frame(predicted[k])
        np.testing.assert_allclose(basis[k], one_basis, rtol=0, atol=0)
        np.testing.assert_allclose(proj[k], one_proj, rtol=1e-15, atol=0)
        np.testing.assert_allclose(moved[k], transport(cov[k], predicted[k], solution[k]), rtol=1e-13, atol=1e-18)
        pc = proj[k] @ cov[k]
        blocks = transported_blocks(cov[k][idx[:, :, None], idx[:, None, :]], transport_offset(predicted[k], solution[k], (basis[k], proj[k])), pc,
                                    pc @ proj[k].T)
        np.testing.assert_allclose(blocks, moved[k][idx[:, :, None], idx[:, None, :]], rtol=1e-12, atol=1e-18)
    keep = np.array([True, False, True, True, False])
    sub_basis, sub_proj = gauge_frame(predicted[0], keep)
    own_basis, own_proj = gauge_frame(predicted[0][keep])
    rows = idx[keep].ravel()
    np.testing.assert_allclose(sub_basis[rows], own_basis, rtol=0, atol=1e-15)
    np.testing.assert_allclose(sub_proj[:, rows], own_proj, rtol=1e-14, atol=1e-16)
    assert not sub_basis[idx[~keep].ravel()].any() and not sub_proj[:, idx[~keep].ravel()].any()
    np.testing.assert_allclose(sub_proj @ sub_basis, np.eye(3), atol=1e-14)


def test_one_update_is_consistent_in_monte_carlo():
    """Truths drawn from the prior, observations drawn from the truths: the mean NEES of the joint
    update over the 3n components is 1 within its chi-square band (300 draws, 10 robots)."""
    rng = np.random.default_rng(7)
    n, draws = 10, 300
    grid = 0.2 * np.column_stack([np.arange(n) % 4, np.arange(n) // 4])  # 0.2 m apart: no pair ever coincides
    mean = np.column_stack([grid + rng.uniform(-0.03, 0.03, (n, 2)), rng.uniform(-np.pi, np.pi, n)])
    cov = np.broadcast_to(np.diag([0.02**2, 0.02**2, 0.05**2]), (n, 3, 3)).copy()
    prior = SwarmEstimate(np.arange(n), mean, cov)
    chol = np.linalg.cholesky(cov)
    loc = make_localizer("joint", CFG)
    nees = []
    for k in range(draws):
        truth = mean + np.einsum("nab,nb->na", chol, rng.normal(size=(n, 3)))
        obs = sense_swarm(truth, prior.ids, CFG, robot_rngs(k, prior.ids, Stream.SENSING))
        est = loc.localize(prior, StepCommands.stationary(prior.ids), obs)
        e = truth - est.poses
        e[:, 2] = wrap_angle(e[:, 2])
        nees.append(e.ravel() @ np.linalg.solve(est.joint, e.ravel()))
    dof = 3 * n * draws
    low, high = chi2.ppf([0.001, 0.999], dof) / dof
    assert low < np.sum(nees) / dof < high


HIGH = scaled(CFG, 5.58)  # the calibrated motion noise of docs/experiments.md: turn 16.7 deg, drive 28 %


def test_motion_moments_are_the_moments_of_the_motion():
    """Monte Carlo (200k draws) of apply_motion from a correlated Gaussian pose (heading at the +-pi seam) with
    large turn and drive noise: motion_moments' mean and covariance are the sample's (the first order's
    covariance is not: it misses the product of the drive and heading errors), and its Jacobian Fx is the
    regression of the post-step pose on the pre-step pose, Cov(x', x) = Fx P."""
    rng = np.random.default_rng(4)
    p = np.array([[4e-4, 1e-4, 2e-4], [1e-4, 2e-4, -1e-4], [2e-4, -1e-4, 0.1**2]])
    pose, command = np.array([0.2, -0.1, np.pi - 0.05]), np.array([0.4, 0.45])
    mean, fx, noise = motion_moments(pose, p, command, HIGH)
    draws = 200_000
    start = pose + rng.normal(size=(draws, 3)) @ np.linalg.cholesky(p).T
    turn, drive = draw_motion_noise(rng, (draws,), HIGH)
    after = apply_motion(start, np.broadcast_to(command, (draws, 2)), turn, drive)
    err = after - mean
    err[:, 2] = wrap_angle(err[:, 2])  # the mean heading is wrapped: it crossed the seam
    want = np.cov(err.T)
    cov = fx @ p @ fx.T + noise
    assert np.all(np.abs(err.mean(axis=0)) < 4 * np.sqrt(np.diag(cov) / draws))
    assert np.abs((cov - want) / np.sqrt(np.outer(np.diag(want), np.diag(want)))).max() < 0.01  # as correlations
    cross = (err - err.mean(axis=0)).T @ (start - start.mean(axis=0)) / draws
    assert np.abs((cross - fx @ p) / np.sqrt(np.outer(np.diag(want), np.diag(p)))).max() < 0.01
    nees = np.einsum("ka,ab,kb->k", err, np.linalg.inv(cov), err) / 3
    assert nees.mean() == pytest.approx(1.0, abs=0.02)
    first = motion_covariance(pose, p, command, HIGH)
    first_err = after - apply_motion(pose, command)
    first_err[:, 2] = wrap_angle(first_err[:, 2])
    first_nees = np.einsum("ka,ab,kb->k", first_err, np.linalg.inv(first), first_err) / 3
    assert first_nees.mean() > 2.0  # first order: overconfident at this noise
    small = motion_moments(pose, p * 1e-4, command, scaled(CFG, 0.01))  # vanishing noise: the first order
    np.testing.assert_allclose(small[1] @ (p * 1e-4) @ small[1].T + small[2], motion_covariance(pose, p * 1e-4, command, scaled(CFG, 0.01)),
                               rtol=1e-3, atol=1e-15)


def test_exact_joint_propagation_regresses_on_the_other_robots():
    """propagate_joint(exact): the cross-covariance of a mover with any other robot is Fx_i P_ij (Stein's lemma),
    its own block motion_moments', a robot that does not move keeps its rows."""
    case = random_step(4, HIGH, np.random.default_rng(2))
    prior = SwarmEstimate.from_joint(case.prior.ids, case.prior.poses, random_joint(4, 2) * 30)
    out = propagate_joint(prior, case.step, HIGH, exact=True)
    cmd = np.where(case.step.moving[:, None], case.step.commands, 0.0)
    _, fx, noise = motion_moments(prior.poses, prior.cov, cmd, HIGH)
    p = prior.joint.reshape(4, 3, 4, 3)
    for i in range(4):
        for j in range(4):
            want = fx[i] @ p[i, :, j] @ fx[j].T + (noise[i] if i == j else 0.0)
            np.testing.assert_allclose(out[3 * i : 3 * i + 3, 3 * j : 3 * j + 3], want, rtol=1e-12, atol=1e-18)
    still = np.flatnonzero(~case.step.moving)
    assert still.size and np.array_equal(fx[still], np.broadcast_to(np.eye(3), (still.size, 3, 3))) and not noise[still].any()


def test_a_moving_update_is_consistent_at_high_motion_noise():
    """One step at the calibrated noise (turn 16.7 deg, drive 28 %): truths drawn from a correlated prior (a heading at
    the +-pi seam), four robots driving 0.25 m towards four standing ones, observations from the truths. The joint
    NEES of the update over its 3n components is 1 within its chi-square band. With the first-order dead reckoning it
    was 1.30 (positions 1.44): the prior claimed the position across a mover's heading known to the heading's error
    times the drive, and the drive error times the heading error was missing."""
    rng = np.random.default_rng(1)
    n, draws = 8, 150
    moving = np.arange(n) >= 4
    mean = np.column_stack([0.3 * (np.arange(n) % 4), np.where(moving, 0.45, 0.0), np.where(moving, -np.pi / 2 - 0.4, 0.3)])
    mean[6, 2] = np.pi / 2 - 0.4 - 1e-3  # faces away, turns back over the seam
    cmd = np.column_stack([np.where(moving, 0.4, 0.0), np.where(moving, 0.25, 0.0)])
    cmd[6, 0] = 0.4 - np.pi
    cov = np.broadcast_to(np.array([[1e-4, 5e-5, 1e-5], [5e-5, 1e-4, -2e-5], [1e-5, -2e-5, 0.03**2]]), (n, 3, 3)).copy()
    prior, step = SwarmEstimate(np.arange(n), mean, cov), StepCommands(np.arange(n), cmd, moving)
    chol = np.linalg.cholesky(cov)
    loc = make_localizer("joint", HIGH)
    full = pos = 0.0
    for k in range(draws):
        start = mean + np.einsum("nab,nb->na", chol, rng.normal(size=(n, 3)))
        turn, drive = draw_motion_noise(rng, (n,), HIGH)
        truth = np.where(moving[:, None], apply_motion(start, cmd, turn, drive), start)
        est = loc.localize(prior, step, sense_swarm(truth, prior.ids, HIGH, robot_rngs(k, prior.ids, Stream.SENSING)))
        e = truth - est.poses
        e[:, 2] = wrap_angle(e[:, 2])
        full += e.ravel() @ np.linalg.solve(est.joint, e.ravel())
        pos += 2 * n * position_nees(truth, est.poses, est.cov)
    dof = 3 * n * draws
    low, high = chi2.ppf([0.001, 0.999], dof) / dof
    assert low < full / dof < high
    assert 0.85 < pos / (2 * n * draws) < 1.15  # robots' errors are correlated: no chi-square band for their sum


def _block(cov: np.ndarray) -> np.ndarray:
    n = len(cov)
    out = np.zeros((3 * n, 3 * n))
    for k in range(n):
        out[3 * k : 3 * k + 3, 3 * k : 3 * k + 3] = cov[k]
    return out


def test_position_nees_takes_correlated_covariances():
    """Known answer with correlated (non-diagonal) 2x2 position blocks and headings near +-pi: e^T P^-1 e / 2 by a
    linear solve, robot by robot; an error along the long axis of a thin ellipse counts little, across it a lot."""
    rng = np.random.default_rng(3)
    a = rng.normal(size=(5, 3, 3)) * 0.01
    cov = a @ np.swapaxes(a, 1, 2) + np.diag([1e-6, 1e-6, 1e-4])
    truth = np.column_stack([rng.normal(size=(5, 2)), np.full(5, np.pi - 1e-3)])
    poses = truth + np.column_stack([rng.normal(0, 0.01, (5, 2)), np.full(5, 2e-3)])
    e = truth[:, :2] - poses[:, :2]
    want = np.mean([e[k] @ np.linalg.solve(cov[k, :2, :2], e[k]) for k in range(5)]) / 2
    assert position_nees(truth, poses, cov) == pytest.approx(want, rel=1e-10)
    thin = np.array([[[1.0, 0.999, 0.0], [0.999, 1.0, 0.0], [0.0, 0.0, 1.0]]]) * 1e-4
    along, across = np.array([[0.01, 0.01, 0.0]]), np.array([[0.01, -0.01, 0.0]])
    assert position_nees(along, np.zeros((1, 3)), thin) == pytest.approx(0.5 * 2e-4 / (1.999e-4), rel=1e-12)
    assert position_nees(across, np.zeros((1, 3)), thin) == pytest.approx(0.5 * 2e-4 / (0.001e-4), rel=1e-9)


def test_position_nees_known_answer():
    cov = np.zeros((2, 3, 3))
    cov[:, 0, 0], cov[:, 1, 1], cov[:, 2, 2] = 0.01, 0.04, 1.0
    truth = np.array([[0.1, 0.0, 0.0], [0.0, 0.2, 0.0]])
    assert position_nees(truth, np.zeros((2, 3)), cov) == pytest.approx(((1.0 + 1.0) / 2) / 2)
    zero = np.zeros((2, 3, 3))
    assert position_nees(truth, np.zeros((2, 3)), zero) == np.inf
    low, high = chi2_band(10, 4)
    assert low < 1.0 < high and high - low < 0.7


