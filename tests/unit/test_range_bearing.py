"""Known answers for the whitened residuals of the joint formulation (coordinator/localization/range_bearing.py)
and the Cramer-Rao bound built from them (crlb.py).

References are independent of the code: residuals written out from the module docstring's formulas
(range |x_j - x_i| - rho, bearing atan2(x_j - x_i) - theta_i - phi, bearing sigma
s_b sqrt(1 + (3 s_r / rho)^4)), Jacobians by central differences of those formulas, and
whitening matrices checked through W^T W = P^-1.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from coordinator.localization.crlb import crlb_pose_covariances, fisher_information
from coordinator.localization.range_bearing import (
    COV_FLOOR,
    DIST_FLOOR,
    GATE_SIGMAS,
    bearing_weights,
    joint_prior_terms,
    joint_sqrt_information,
    observation_residuals,
    observation_terms,
    prior_terms,
    sensor_sigmas,
    sqrt_information,
    stack_terms,
)
from coordinator.localization.sparse_lm import PoseLayout, dense
from runtime.models.config import ModelConfig
from runtime.models.geometry import wrap_angle

CFG = ModelConfig(range_sigma_m=0.01, bearing_sigma_rad=0.02)


def wrap(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def reference_residuals(flat, observer, observed, rho, phi, s_r, s_b):
    """[range_0, bearing_0, range_1, ...] whitened, written from the module docstring."""
    p = flat.reshape(-1, 3)
    out = []
    for i, j, r, b in zip(observer, observed, rho, phi, strict=True):
        dx, dy = p[j, 0] - p[i, 0], p[j, 1] - p[i, 1]
        sigma_b = s_b * math.sqrt(1 + (3 * s_r / r) ** 4)
        out += [(math.hypot(dx, dy) - r) / s_r, float(wrap(math.atan2(dy, dx) - p[i, 2] - b)) / sigma_b]
    return np.array(out)


def numeric_jacobian(f, x, h=1e-7):
    cols = []
    for k in range(len(x)):
        e = np.zeros_like(x)
        e[k] = h
        cols.append((f(x + e) - f(x - e)) / (2 * h))
    return np.column_stack(cols)


def test_sensor_sigmas_are_floored_for_noise_free_sensing():
    assert sensor_sigmas(CFG) == (0.01, 0.02)
    assert sensor_sigmas(ModelConfig(range_sigma_m=0.0, bearing_sigma_rad=0.0)) == (1e-9, 1e-9)


def test_bearing_weights_by_hand():
    """s_r = 0.01, s_b = 0.02, gate 3 s_r = 0.03: at rho = 0.03 the bearing sigma is s_b sqrt(2);
    at rho = 0.06 it is s_b sqrt(1 + 1/16); far away (10 m) it is s_b; at rho = 0 the weight is 0."""
    assert GATE_SIGMAS == 3.0
    w = bearing_weights(np.array([0.0, 0.03, 0.06, 10.0]), CFG)
    np.testing.assert_allclose(w, [0, 1 / (0.02 * math.sqrt(2)), 1 / (0.02 * math.sqrt(17 / 16)), 50], rtol=1e-9)
    assert bearing_weights([0.03], CFG)[0] == pytest.approx(1 / (0.02 * math.sqrt(2)))  # lists accepted


def test_observation_residuals_and_jacobian_match_the_formulas():
    """Three robots, four observations with asymmetric geometry (one at 0.04 m, inside the gate): residuals
    equal the docstring's formulas and the Jacobian their central differences."""
    poses = np.array([[0.0, 0.0, 0.3], [0.3, 0.1, -2.0], [0.1, 0.35, 3.0]])
    poses_near = poses.copy()
    poses_near[2, :2] = poses[1, :2] + [0.03, 0.025]
    observer, observed = np.array([0, 1, 2, 2]), np.array([1, 2, 0, 1])
    rho = np.array([0.31, 0.30, 0.37, 0.04])
    phi = np.array([0.0, 1.9, -1.8, 0.5])
    layout = PoseLayout(np.ones(3, bool), np.ones(3, bool))
    for p in (poses, poses_near):
        res, (rows, cols, vals) = observation_terms(p, layout, observer, observed, rho, phi, CFG)
        ref = reference_residuals(p.ravel(), observer, observed, rho, phi, 0.01, 0.02)
        np.testing.assert_allclose(res, ref, rtol=1e-9, atol=1e-9)
        jac = dense(stack_terms(9, (res, (rows, cols, vals)))[1])
        num = numeric_jacobian(lambda x: reference_residuals(x, observer, observed, rho, phi, 0.01, 0.02), p.ravel())
        np.testing.assert_allclose(jac, num, rtol=1e-5, atol=1e-4)


def test_bearing_residual_is_wrapped():
    """Robot 1 due west of robot 0 (true bearing pi), measured -pi + 0.01: the residual is -0.01 / s_b(rho),
    not 2 pi - 0.01."""
    poses = np.array([[0.0, 0.0, 0.0], [-0.5, 0.0, 0.0]])
    layout = PoseLayout(np.ones(2, bool), np.ones(2, bool))
    res, _ = observation_terms(poses, layout, np.array([0]), np.array([1]), np.array([0.5]), np.array([-np.pi + 0.01]), CFG)
    assert res[0] == pytest.approx(0.0, abs=1e-12)
    assert res[1] == pytest.approx(-0.01 * bearing_weights(np.array([0.5]), CFG)[0], rel=1e-6)


def test_fixed_components_drop_out_of_the_jacobian():
    """Robot 0 entirely fixed, robot 1's heading fixed: unknowns are robot 1's (x, y) only, columns 0-1;
    the Jacobian is the reference's columns 3 and 4."""
    poses = np.array([[0.0, 0.0, 0.2], [0.2, 0.1, 1.0]])
    observer, observed, rho, phi = np.array([0, 1]), np.array([1, 0]), np.array([0.25, 0.2]), np.array([0.1, 2.5])
    layout = PoseLayout(np.array([False, True]), np.array([False, False]))
    res, trip = observation_terms(poses, layout, observer, observed, rho, phi, CFG)
    jac = dense(stack_terms(layout.size, (res, trip))[1])
    num = numeric_jacobian(lambda x: reference_residuals(x, observer, observed, rho, phi, 0.01, 0.02), poses.ravel())
    np.testing.assert_allclose(jac, num[:, [3, 4]], rtol=1e-5, atol=1e-4)


def test_sqrt_information_whitens():
    """W^T W = P^-1 for an SPD P; a singular P = diag(4, 1, 0) gives W^T W = diag(1/4, 1, 1e12) (floor
    1e-12); a slightly asymmetric P is symmetrised first."""
    assert COV_FLOOR == 1e-12
    a = np.array([[2.0, 0.3, 0.1], [0.3, 1.0, -0.2], [0.1, -0.2, 0.5]])
    cov = np.stack([a, np.diag([4.0, 1.0, 0.0]), a + np.array([[0, 0.02, 0], [-0.02, 0, 0], [0, 0, 0]])])
    w = sqrt_information(cov)
    wtw = np.swapaxes(w, -1, -2) @ w
    np.testing.assert_allclose(wtw[0], np.linalg.inv(a), rtol=1e-10)
    np.testing.assert_allclose(wtw[1], np.diag([0.25, 1.0, 1e12]), rtol=1e-10, atol=1e-6)
    np.testing.assert_allclose(wtw[2], np.linalg.inv(a), rtol=1e-10)


def test_prior_residuals_wrap_the_heading_and_have_the_whitening_as_jacobian():
    """Prior mean (1, 2, pi - 0.05), pose (1.1, 1.9, -pi + 0.05): the difference is (0.1, -0.1, 0.1) after
    wrapping; with P = diag(0.01, 0.04, 0.25) the residual is (1, -0.5, 0.2) and the Jacobian diag(10, 5, 2)."""
    poses = np.array([[1.1, 1.9, -np.pi + 0.05], [0.0, 0.0, 0.0]])
    mean = np.array([[1.0, 2.0, np.pi - 0.05], [0.0, 0.0, 0.0]])
    cov = np.stack([np.diag([0.01, 0.04, 0.25]), np.eye(3)])
    layout = PoseLayout(np.ones(2, bool), np.ones(2, bool))
    res, trip = prior_terms(poses, layout, mean, sqrt_information(cov))
    np.testing.assert_allclose(np.abs(res[:3]), [1.0, 0.5, 0.2], rtol=1e-9)
    jac = dense(stack_terms(6, (res, trip))[1])
    np.testing.assert_allclose(jac.T @ jac, np.diag([100, 25, 4, 1, 1, 1]), rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(jac @ np.array([0.1, -0.1, 0.1, 0, 0, 0]), res, atol=1e-12)
    assert mean[0, 2] == np.pi - 0.05  # inputs untouched


def test_joint_sqrt_information_whitens_spd_and_indefinite_joints():
    """An SPD joint P: W^T W = P^-1 (the 1e-12 floor is negligible). An indefinite one, diag(1, -1, 4):
    eigenvalues floored, W^T W = diag(1, 1e12, 1/4)."""
    rng = np.random.default_rng(3)
    a = rng.normal(size=(6, 6))
    joint = a @ a.T + 0.5 * np.eye(6)
    w = joint_sqrt_information(joint)
    np.testing.assert_allclose(w.T @ w, np.linalg.inv(joint), rtol=1e-8, atol=1e-10)
    w2 = joint_sqrt_information(np.diag([1.0, -1.0, 4.0]))
    np.testing.assert_allclose(w2.T @ w2, np.diag([1.0, 1e12, 0.25]), rtol=1e-10, atol=1e-6)


def test_joint_prior_terms_by_hand():
    """Joint prior of 2 robots, W = sqrt-information of a correlated 6x6 P: the residual is W (p - mu)
    with the heading difference wrapped, and the Jacobian W (robot 0's heading fixed: column 2 of W removed)."""
    rng = np.random.default_rng(4)
    a = rng.normal(size=(6, 6))
    w = joint_sqrt_information(a @ a.T + np.eye(6))
    poses = np.array([[0.1, 0.2, np.pi - 0.01], [0.5, -0.1, 0.3]])
    mean = np.array([[0.0, 0.25, -np.pi + 0.01], [0.45, 0.0, 0.2]])
    diff = np.array([0.1, -0.05, -0.02, 0.05, -0.1, 0.1])
    full = PoseLayout(np.ones(2, bool), np.ones(2, bool))
    res, trip = joint_prior_terms(poses, full, mean, w)
    np.testing.assert_allclose(res, w @ diff, atol=1e-12)
    np.testing.assert_allclose(dense(stack_terms(6, (res, trip))[1]), w, atol=1e-12)
    part = PoseLayout(np.ones(2, bool), np.array([False, True]))
    res2, trip2 = joint_prior_terms(poses, part, mean, w)
    np.testing.assert_allclose(res2, res)
    np.testing.assert_allclose(dense(stack_terms(5, (res2, trip2))[1]), w[:, [0, 1, 3, 4, 5]], atol=1e-12)


def test_stack_terms_offsets_rows():
    """Blocks of 2 and 1 residuals: the second block's row 0 becomes row 2 of the system."""
    r, jac = stack_terms(
        2,
        (np.array([1.0, 2.0]), (np.array([0, 1]), np.array([0, 1]), np.array([3.0, 4.0]))),
        (np.array([5.0]), (np.array([0]), np.array([1]), np.array([6.0]))),
    )
    assert r.tolist() == [1, 2, 5]
    np.testing.assert_array_equal(dense(jac), [[3, 0], [0, 4], [0, 6]])


def reference_fisher(poses, prior_cov, observer, observed, s_r, s_b):
    """J^T J of the reference residuals (observations at their true values) plus the prior information."""
    rho = np.hypot(*(poses[observed, :2] - poses[observer, :2]).T)
    jac = numeric_jacobian(lambda x: reference_residuals(x, observer, observed, rho, np.zeros(len(rho)), s_r, s_b), poses.ravel())
    info = jac.T @ jac
    for i, c in enumerate(prior_cov):
        info[3 * i : 3 * i + 3, 3 * i : 3 * i + 3] += np.linalg.inv(c)
    return info


def test_fisher_information_is_prior_plus_observation_information():
    """Four robots, five observations, asymmetric correlated priors: the Fisher information equals the
    prior informations P_i^-1 on the diagonal blocks plus J^T J of the reference residuals."""
    poses = np.array([[0.0, 0.0, 0.4], [0.3, 0.05, -1.0], [0.1, 0.32, 2.0], [0.42, 0.3, 0.1]])
    rng = np.random.default_rng(5)
    covs = []
    for _ in range(4):
        a = 0.05 * rng.normal(size=(3, 3))
        covs.append(a @ a.T + np.diag([1e-4, 2e-4, 3e-3]))
    covs = np.array(covs)
    observer, observed = np.array([0, 1, 2, 3, 1]), np.array([1, 2, 3, 0, 3])
    info = fisher_information(poses, covs, observer, observed, CFG)
    ref = reference_fisher(poses, covs, observer, observed, 0.01, 0.02)
    np.testing.assert_allclose(info, ref, rtol=1e-5, atol=1e-3 * np.abs(ref).max() * 1e-3)
    blocks = crlb_pose_covariances(poses, covs, observer, observed, CFG)
    inv = np.linalg.inv(ref)
    for i in range(4):
        np.testing.assert_allclose(blocks[i], inv[3 * i : 3 * i + 3, 3 * i : 3 * i + 3], rtol=1e-5, atol=1e-12)
        np.testing.assert_array_equal(blocks[i], blocks[i].T)


def test_crlb_of_a_robot_seen_from_a_known_anchor():
    """Robot 0 known exactly (prior covariance 0, floored to 1e-12), robot 1 with prior diag(s^2, s^2, t^2)
    seen by robot 0 at d = 0.25 m in direction alpha = 30 deg. Robot 1's position information is
    I / s^2 + R diag(1 / s_r^2, (w_b / d)^2) R^T (range along the line of sight, bearing across it,
    w_b = 1 / (s_b sqrt(1 + (3 s_r / d)^4))); its heading is not observed (bearings are in the
    observer's frame): the bound stays t^2. Robot 0's bound is its (floored) prior."""
    s, t, d, alpha = 0.02, 0.1, 0.25, math.radians(30)
    poses = np.array([[0.0, 0.0, 1.2], [d * math.cos(alpha), d * math.sin(alpha), -0.4]])
    covs = np.stack([np.zeros((3, 3)), np.diag([s * s, s * s, t * t])])
    out = crlb_pose_covariances(poses, covs, np.array([0]), np.array([1]), CFG)
    w_b = 1 / (0.02 * math.sqrt(1 + (0.03 / d) ** 4))
    rot = np.array([[math.cos(alpha), -math.sin(alpha)], [math.sin(alpha), math.cos(alpha)]])
    pos_info = np.eye(2) / s**2 + rot @ np.diag([1 / 0.01**2, (w_b / d) ** 2]) @ rot.T
    np.testing.assert_allclose(out[1, :2, :2], np.linalg.inv(pos_info), rtol=1e-6, atol=1e-13)
    assert out[1, 2, 2] == pytest.approx(t * t, rel=1e-6)
    np.testing.assert_allclose(out[1, :2, 2], 0, atol=1e-12)
    np.testing.assert_allclose(out[0], 1e-12 * np.eye(3), rtol=1e-3, atol=1e-18)


def test_crlb_without_observations_is_the_prior():
    """No observation: the bound of each robot is its prior covariance."""
    covs = np.stack([np.diag([1e-4, 4e-4, 1e-2]), np.array([[2e-4, 5e-5, 0], [5e-5, 1e-4, 1e-5], [0, 1e-5, 3e-3]])])
    out = crlb_pose_covariances(np.zeros((2, 3)), covs, [], [], CFG)  # empty lists are index arrays too
    np.testing.assert_allclose(out, covs, rtol=1e-9, atol=1e-18)


def test_observation_residuals_one_definition_two_evaluations():
    """``observation_residuals`` evaluates one swarm's observations (hypot, wrapped angle difference) and the batch's
    (square root of the squares, angle in the rotated frame, into scratch arrays) to the same values: range and
    bearing residuals and |d|, on random pairs, near-coincident robots (|d| floored) and directions at the +-pi seam."""
    rng = np.random.default_rng(5)
    k = 400
    dx, dy = rng.normal(0.0, 0.3, k), rng.normal(0.0, 0.3, k)
    dx[:3], dy[:3] = 0.0, [0.0, 1e-12, -2e-10]  # coincident and near-coincident
    direction = np.arctan2(dy, dx) + rng.normal(0.0, 0.05, k)
    direction[3:6] = np.arctan2(dy[3:6], dx[3:6]) - np.pi + np.array([1e-9, 0.0, -1e-9])  # the seam
    direction[6:9] += 2 * np.pi * np.array([3, -2, 1])  # unwrapped headings
    rho, w_b = np.abs(rng.normal(0.3, 0.1, k)), rng.uniform(0.5, 30.0, k)
    one = observation_residuals(dx, dy, rho, 100.0, w_b, direction=direction)
    scratch = tuple(np.empty(k) for _ in range(3))
    batch = observation_residuals(dx, dy, rho, 100.0, w_b, cos_sin=(np.cos(direction), np.sin(direction)), scratch=scratch)
    np.testing.assert_allclose(batch[0], one[0], rtol=1e-13, atol=1e-12)
    np.testing.assert_allclose(batch[2], one[2], rtol=1e-15)
    assert one[2][:3].tolist() == [DIST_FLOOR] * 3
    defined = slice(1, None)  # exactly coincident robots (0): no direction (atan2 of signed zeros), gated by w_b in use
    angle_gap = wrap_angle((batch[1] - one[1]) / w_b)[defined]  # +-pi at the seam is the same angle
    np.testing.assert_allclose(angle_gap, 0.0, atol=1e-12)
    want = wrap_angle(np.arctan2(dy, dx) - direction) * w_b
    np.testing.assert_allclose(wrap_angle((one[1] - want) / w_b), 0.0, atol=1e-12)
