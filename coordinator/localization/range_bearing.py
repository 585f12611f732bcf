"""Whitened residuals and Jacobians of the joint (Graph-SLAM-like) formulation (Section 5.3).

Unknowns are robot poses (x, y, theta). Two kinds of residuals:

* observation (i sees j): ((|x_j - x_i| - rho_ij) / s_r, wrap(atan2(x_j - x_i) - theta_i - phi_ij) / s_b(rho_ij))
* prior: W_i (p_i - mu_i), W_i^T W_i = P_i^-1 (dead-reckoning mean and covariance)

Near-coincident robots: the bearing of a robot a few millimetres away means nothing (the
range sensor alone puts it anywhere within s_r), and its Jacobian grows like 1 / range.
The bearing sigma is therefore gated smoothly by the measured range,
s_b(rho) = s_b sqrt(1 + (GATE_SIGMAS s_r / rho)^4): unchanged beyond a few range sigmas
(+0.01 % at 0.25 m with the defaults), meaningless below (a 0-range observation keeps only
its range). It depends on the measurement, not on the estimate, so the problem stays a
fixed weighted least squares (docs/localization.md).

They are shared by the joint localizer and the Cramer-Rao bound, whose Fisher
information is exactly J^T J of these residuals at the true poses.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import cast

import numpy as np
import scipy.sparse as sp

from coordinator.localization.sparse_lm import PoseLayout, jacobian
from runtime.models.config import ModelConfig
from runtime.models.geometry import wrap_angle

COV_FLOOR = 1e-12  # smallest prior variance, so an exact prior stays invertible
GATE_SIGMAS = 3.0  # range sigmas below which a bearing loses its weight (s_b(rho) doubles at ~0.84 of this)
DIST_FLOOR = 1e-9  # m: robots closer than this are taken this far apart (range residual and derivatives stay finite)


def sqrt_information(cov: np.ndarray) -> np.ndarray:
    """W (n, 3, 3) with W^T W = cov^-1, eigenvalues of cov floored at ``COV_FLOOR``.

    W = diag(lambda^-1/2) V^T from the eigendecomposition of the symmetrised covariance,
    so covariances that are singular (an exact prior) or slightly indefinite after
    numerical propagation still whiten.
    """
    sym = 0.5 * (cov + np.swapaxes(cov, -1, -2))
    lam, vec = np.linalg.eigh(sym)
    lam = np.maximum(lam, COV_FLOOR)
    return cast(np.ndarray, np.swapaxes(vec, -1, -2) / np.sqrt(lam)[..., :, None])


def sensor_sigmas(cfg: ModelConfig) -> tuple[float, float]:
    """(range sigma m, bearing sigma rad) used for whitening, floored at 1e-9 for noise-free sensing."""
    return max(cfg.range_sigma_m, 1e-9), max(cfg.bearing_sigma_rad, 1e-9)


def bearing_weights(range_m: np.ndarray, cfg: ModelConfig) -> np.ndarray:
    """1 / s_b(rho) (1/rad): the whitening weight of each bearing given its measured range ``range_m`` (m).

    s_b(rho) = s_b sqrt(1 + (GATE_SIGMAS s_r / rho)^4), written as rho^2 / (s_b sqrt(rho^4 + g^4))
    so that a zero range gives weight 0 (no division by zero).
    """
    s_r, s_b = sensor_sigmas(cfg)
    rho2 = np.square(np.asarray(range_m, dtype=float))
    gate2 = (GATE_SIGMAS * s_r) ** 2
    return cast(np.ndarray, rho2 / (s_b * np.sqrt(rho2 * rho2 + gate2 * gate2)))


def observation_residuals(
    dx: np.ndarray,
    dy: np.ndarray,
    range_m: np.ndarray,
    w_r: np.ndarray | float,
    w_b: np.ndarray,
    *,
    direction: np.ndarray | None = None,
    cos_sin: tuple[np.ndarray, np.ndarray] | None = None,
    out: Sequence[np.ndarray | None] | None = None,
    scratch: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Whitened residuals of observations i -> j, elementwise over arrays of any (common) shape: the one
    definition of the joint problem's observation terms, for one swarm (``observation_blocks``) and for the
    planner's batch (``batch``).

    ``dx``, ``dy``: d = x_j - x_i (m); ``range_m``: rho_ij (m); ``w_r``: 1 / s_r (or 0 where there is no
    observation); ``w_b``: ``bearing_weights``. The measured direction theta_i + phi_ij (rad) is given as
    ``direction`` or as its (cos, sin) ``cos_sin``. Returns (range residual (|d| - rho) w_r, bearing residual
    w_b times the angle of d seen from the measured direction, wrap(atan2(d) - theta_i - phi_ij), |d|), |d|
    floored at ``DIST_FLOOR``.

    Two evaluations of the same values (to rounding), chosen by what is cheap: one swarm (no ``scratch``: tens
    to thousands of values, where each numpy call costs more than its values) takes hypot and the wrapped
    difference of angles; the batch (``scratch``: three arrays for the intermediate values, and ``cos_sin``)
    takes the square root of the squares and the angle of d rotated into the measured direction, since hypot,
    the wrap (a float modulo) and the trigonometry of every pair are several times slower per value. ``out``:
    the three result arrays to write into (the batch reuses its own: fresh large arrays cost page faults).
    """
    r_range, r_bearing, dist = (None, None, None) if out is None else out
    # outputs are passed positionally: numpy parses ``out=`` keywords ~0.25 us slower per call
    if scratch is None:
        dist = np.hypot(dx, dy, dist)
    else:
        t1, t2, t3 = scratch
        dist = np.multiply(dx, dx, dist)
        dist += np.multiply(dy, dy, t1)
        np.sqrt(dist, dist)
    np.maximum(dist, DIST_FLOOR, out=dist)
    r_range = np.subtract(dist, range_m, r_range)
    r_range *= w_r
    if scratch is None:
        if direction is None:
            assert cos_sin is not None, "direction or cos_sin"
            direction = np.arctan2(cos_sin[1], cos_sin[0])
        r_bearing = np.arctan2(dy, dx, r_bearing)
        r_bearing -= direction
        r_bearing += np.pi  # wrap to [-pi, pi), as geometry.wrap_angle
        np.mod(r_bearing, 2.0 * np.pi, r_bearing)
        r_bearing -= np.pi
    else:
        cos_a, sin_a = (np.cos(direction), np.sin(direction)) if cos_sin is None else cos_sin  # type: ignore[arg-type]  # one given
        along = np.multiply(dx, cos_a, t1)  # d in the frame of the measured direction
        along += np.multiply(dy, sin_a, t2)
        across = np.multiply(dy, cos_a, t2)
        across -= np.multiply(dx, sin_a, t3)
        r_bearing = np.arctan2(across, along, r_bearing)
    r_bearing *= w_b
    return r_range, r_bearing, dist


def observation_jacobian(
    dx: np.ndarray,
    dy: np.ndarray,
    inv_dist: np.ndarray,
    w_r: np.ndarray | float,
    w_b: np.ndarray,
    out: Sequence[np.ndarray | None] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Derivatives of ``observation_residuals``' whitened residuals with respect to the observed robot's position
    x_j, elementwise over arrays of any (common) shape: the one definition of the joint problem's Jacobian, for one
    swarm (``observation_blocks``, the sparse assembly) and for the planner's batch (its dense J^T J).

    ``dx``, ``dy``: d = x_j - x_i (m); ``inv_dist``: 1 / |d| (as floored by ``observation_residuals``); ``w_r``,
    ``w_b``: the whitening weights. Returns (d range / d x_j = w_r d / |d| (two arrays), d bearing / d x_j =
    w_b (-d_y, d_x) / |d|^2 (two arrays)). The rest of the 2 x 5 block over (x_i, y_i, theta_i, x_j, y_j) follows:
    d / d x_i = -d / d x_j, d range / d theta_i = 0, d bearing / d theta_i = -w_b. ``out``: four arrays to write into.
    """
    o = (None, None, None, None) if out is None else out  # outputs positional: faster than ``out=`` keywords
    f = np.multiply(inv_dist, w_r, o[1])  # w_r / |d|
    range_x = np.multiply(dx, f, o[0])
    range_y = np.multiply(dy, f, f)
    g = np.multiply(inv_dist, w_b, o[3])
    g *= inv_dist  # w_b / |d|^2
    bearing_x = np.multiply(dy, g, o[2])
    np.negative(bearing_x, bearing_x)
    bearing_y = np.multiply(dx, g, g)
    return range_x, range_y, bearing_x, bearing_y


def observation_blocks(
    poses: np.ndarray,
    observer: np.ndarray,
    observed: np.ndarray,
    range_m: np.ndarray,
    bearing_rad: np.ndarray,
    cfg: ModelConfig,
    w_b: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Whitened residuals (m, 2) = (range, bearing) of each observation and their Jacobians (m, 2, 5)
    over the five unknowns they depend on, (x_i, y_i, theta_i, x_j, y_j) of observer i and observed j.

    Bearings are whitened by ``bearing_weights`` of their measured range ``range_m`` (pass them as
    ``w_b`` when they are already known: they do not change while the observations do not).
    """
    s_r, _ = sensor_sigmas(cfg)
    w_b = bearing_weights(range_m, cfg) if w_b is None else w_b
    at_i = poses[observer]
    d = poses[observed, :2] - at_i[:, :2]
    direction = at_i[:, 2] + bearing_rad
    residual = np.empty((len(observer), 2))
    _, _, dist = observation_residuals(d[:, 0], d[:, 1], range_m, 1.0 / s_r, w_b, direction=direction, out=(residual[:, 0], residual[:, 1], None))
    jac = np.empty((len(observer), 2, 5))  # filled column by column (one np.stack each cost more at n = 10)
    observation_jacobian(d[:, 0], d[:, 1], 1.0 / dist, 1.0 / s_r, w_b, out=(jac[:, 0, 3], jac[:, 0, 4], jac[:, 1, 3], jac[:, 1, 4]))
    np.negative(jac[:, :, 3:], out=jac[:, :, :2])  # d / d x_i = -d / d x_j
    jac[:, 0, 2] = 0.0
    np.negative(w_b, out=jac[:, 1, 2])
    return residual, jac


def observation_terms(
    poses: np.ndarray,
    layout: PoseLayout,
    observer: np.ndarray,
    observed: np.ndarray,
    range_m: np.ndarray,
    bearing_rad: np.ndarray,
    cfg: ModelConfig,
) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """``observation_blocks`` as residuals (2m,) ordered [range_0, bearing_0, range_1, ...] and COO Jacobian triplets."""
    residual, jac = observation_blocks(poses, observer, observed, range_m, bearing_rad, cfg)
    ci, cj = layout.cols[observer], layout.cols[observed]
    cols5 = np.stack([ci[:, 0], ci[:, 1], ci[:, 2], cj[:, 0], cj[:, 1]], axis=1)  # (m, 5)
    rows = np.broadcast_to(np.arange(2 * len(observer)).reshape(-1, 2, 1), jac.shape)
    cols = np.broadcast_to(cols5[:, None, :], jac.shape)
    return residual.ravel(), (rows.ravel(), cols.ravel(), jac.ravel())


def pose_difference(poses: np.ndarray, mean: np.ndarray) -> np.ndarray:
    """p - mu (..., n, 3) of the prior terms, heading differences wrapped (one swarm or a batch)."""
    diff = poses - mean
    diff[..., 2] = wrap_angle(diff[..., 2])
    return cast(np.ndarray, diff)


def prior_information(cov: np.ndarray) -> np.ndarray:
    """W^T W (..., 3, 3) for the whitening W = ``sqrt_information(cov)`` of the prior terms, one swarm or a batch.

    That is the inverse of the symmetrised covariance with its eigenvalues floored at
    ``COV_FLOOR``. Where every eigenvalue is clearly above the floor (Sylvester's criterion
    on sym - 2 floor I) the floor does nothing and the plain inverse (by cofactors) gives the same matrix,
    much faster than the eigendecompositions; the others go through ``sqrt_information``.
    """
    sym = 0.5 * (cov + np.swapaxes(cov, -1, -2))
    m = sym - 2.0 * COV_FLOOR * np.eye(3)
    a, b, c, d, e, f = m[..., 0, 0], m[..., 1, 1], m[..., 2, 2], m[..., 0, 1], m[..., 0, 2], m[..., 1, 2]
    minor2 = a * b - d * d
    det = a * (b * c - f * f) - d * (d * c - f * e) + e * (d * f - b * e)
    clear = (a > 0) & (minor2 > 0) & (det > 0)
    a, b, c, d, e, f = sym[..., 0, 0], sym[..., 1, 1], sym[..., 2, 2], sym[..., 0, 1], sym[..., 0, 2], sym[..., 1, 2]
    cofactors = np.stack([b * c - f * f, e * f - d * c, d * f - b * e, a * c - e * e, d * e - a * f, a * b - d * d], axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        upper = cofactors / (a * cofactors[..., 0] + d * cofactors[..., 1] + e * cofactors[..., 2])[..., None]
    info = upper[..., [0, 1, 2, 1, 3, 4, 2, 4, 5]].reshape(cov.shape)  # the inverse of sym by its cofactors (symmetric)
    if not clear.all():
        w = sqrt_information(cov[~clear])
        info[~clear] = np.swapaxes(w, -1, -2) @ w
    return cast(np.ndarray, 0.5 * (info + np.swapaxes(info, -1, -2)))


def prior_terms(
    poses: np.ndarray, layout: PoseLayout, mean: np.ndarray, sqrt_info: np.ndarray
) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Residuals (3n,) W_i (p_i - mu_i) (heading difference wrapped) and COO triplets."""
    n = len(poses)
    residual = np.einsum("nab,nb->na", sqrt_info, pose_difference(poses, mean)).ravel()
    rows = np.repeat(np.arange(3 * n), 3)
    cols = np.repeat(layout.cols, 3, axis=0).ravel()
    return residual, (rows, cols, sqrt_info.reshape(-1))


def joint_sqrt_information(joint: np.ndarray) -> np.ndarray:
    """W (3n, 3n) with W^T W = joint^-1 (eigenvalues floored at ``COV_FLOOR``), like ``sqrt_information``."""
    sym = 0.5 * (joint + joint.T)
    try:
        chol = np.linalg.cholesky(sym + COV_FLOOR * np.eye(len(sym)))
        return np.linalg.inv(chol)  # W = L^-1: W^T W = (L L^T)^-1
    except np.linalg.LinAlgError:
        lam, vec = np.linalg.eigh(sym)
        return cast(np.ndarray, vec.T / np.sqrt(np.maximum(lam, COV_FLOOR))[:, None])


def joint_prior_terms(
    poses: np.ndarray, layout: PoseLayout, mean: np.ndarray, sqrt_info: np.ndarray
) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Residuals (3n,) W (p - mu) of a prior with joint covariance (W (3n, 3n)) and COO triplets (dense W)."""
    diff = pose_difference(poses, mean)
    k = sqrt_info.shape[0]
    rows = np.repeat(np.arange(k), k)
    cols = np.tile(layout.cols.ravel(), k)
    return sqrt_info @ diff.ravel(), (rows, cols, sqrt_info.ravel())


def stack_terms(
    n_cols: int, *terms: tuple[np.ndarray, tuple[np.ndarray, np.ndarray, np.ndarray]]
) -> tuple[np.ndarray, sp.csr_matrix]:
    """Concatenate residual blocks and their Jacobian triplets into one system."""
    residuals, rows, cols, vals = [], [], [], []
    offset = 0
    for r, (rw, cl, vl) in terms:
        residuals.append(r)
        rows.append(rw + offset)
        cols.append(cl)
        vals.append(vl)
        offset += len(r)
    return np.concatenate(residuals), jacobian(offset, n_cols, np.concatenate(rows), np.concatenate(cols), np.concatenate(vals))
