"""Cramer-Rao lower bound of one localization step (benchmark reference, and the anchor search's prediction).

The post-step poses p (n robots x (x, y, heading)) are estimated from

* the dead-reckoning prior p_i ~ N(mu_i, P_i) per robot (Phase 1.1: the pre-step
  estimate moved by the commands, Eq. 19, with the propagated 3x3 covariance), and
* the range/bearing observations z_ij = (rho_ij, phi_ij) (Eq. 20) of robot j by robot i with noise
  N(0, s_r^2) and N(0, s_b(rho)^2) (``range_bearing.bearing_weights``' gated bearing sigma).

With the prior treated as Gaussian information on p, the (linearised) Bayesian
CRLB is the inverse of the Fisher information

    I = J^T J,

where J is the Jacobian of the whitened residuals (the same residuals the joint
localizer minimises, ``range_bearing.prior_terms`` + ``observation_terms``)
evaluated at the TRUE poses. Any unbiased estimator using only these data has a
per-robot error covariance no smaller than the 3x3 diagonal block C_i of I^-1.
The bound is linearised: it ignores the curvature of the range/bearing models
and the non-Gaussianity of the dead-reckoning prior, so an efficient estimator
can land slightly above it (or, by chance over few trials, below it).

Units: C_i is in m^2 (position block), m*rad and rad^2.
"""

from __future__ import annotations

import numpy as np

from coordinator.localization.range_bearing import DIST_FLOOR, bearing_weights, observation_jacobian, prior_information, sensor_sigmas
from runtime.models.config import ModelConfig


def fisher_informations(
    poses: np.ndarray, prior_cov: np.ndarray, swarm: np.ndarray, observer: np.ndarray, observed: np.ndarray, cfg: ModelConfig
) -> np.ndarray:
    """Fisher information (c, 3n, 3n) of c swarms at ``poses`` (c, n, 3) with dead-reckoning covariances ``prior_cov``
    (c, n, 3, 3), observation k being robot ``observed[k]`` seen by ``observer[k]`` in swarm ``swarm[k]``: the one
    assembly of the bound, for one swarm (``fisher_information``) and for many plans at once (the anchor search's
    ``crlb_rank``). Rows and columns robot by robot (x_0, y_0, heading_0, x_1, ...).

    With d = p_j - p_i, u = d / |d|, v = (-d_y, d_x) / |d|^2 (Eq. 20: rho_ij = |d|, phi_ij = atan2(d) - theta_i, so
    d rho / d p_j = u^T = -d rho / d p_i, d phi / d p_j = v^T = -d phi / d p_i, d phi / d theta_i = -1,
    d rho / d theta_i = 0), an observation i -> j adds H^T R^-1 H with R = diag(s_r^2, s_b(rho)^2), i.e. with
    A = u u^T / s_r^2 + v v^T / s_b^2 (2x2) and h = v / s_b^2:

        I[p_i, p_i] += A,  I[p_j, p_j] += A,  I[p_i, p_j] = I[p_j, p_i]^T -= A,
        I[theta_i, theta_i] += 1 / s_b^2,  I[theta_i, p_i] += h^T,  I[theta_i, p_j] -= h^T,

    and the prior adds P_i^-1 (``prior_information``: eigenvalues floored as the localizers' whitening) to robot i's
    3x3 diagonal block. u and v / s_b are ``range_bearing.observation_jacobian``'s (the joint localizer's Jacobian);
    a pair observed twice counts twice. Assembled by one scatter-add of the entries; every entry and its mirror
    receive the same terms in the same order, so the matrix is symmetric to the last bit.
    """
    c, n, _ = poses.shape
    size = 3 * n
    at = poses[..., :2].reshape(c * n, 2)
    first = swarm * n
    d = at[first + observed] - at[first + observer]
    rho = np.hypot(d[:, 0], d[:, 1])
    s_r, _ = sensor_sigmas(cfg)
    w_b = bearing_weights(rho, cfg)
    range_x, range_y, bearing_x, bearing_y = observation_jacobian(d[:, 0], d[:, 1], 1.0 / np.maximum(rho, DIST_FLOOR), 1.0 / s_r, w_b)
    values = np.stack([range_x * range_x + bearing_x * bearing_x, range_x * range_y + bearing_x * bearing_y,
                       range_y * range_y + bearing_y * bearing_y, w_b * bearing_x, w_b * bearing_y, w_b * w_b])  # (6, m)
    block, within, term = _ENTRIES
    i, j = 3 * observer, 3 * observed  # the first row (and column) of each robot
    corner = swarm * (size * size) + np.stack([i * size + i, j * size + j, i * size + j, j * size + i])  # of (i, i), (j, j), (i, j), (j, i)
    flat = corner[block]  # (entries, m)
    flat += (within // 3 * size + within % 3)[:, None]  # in place: numpy's broadcast add of integers into a new array is ~20x slower
    weights = np.concatenate([values, -values])[term]
    info = np.bincount(flat.ravel(), weights=weights.ravel(), minlength=c * size * size).astype(float, copy=False)  # none: ints
    info = info.reshape(c, n, 3, n, 3)
    index = np.arange(n)
    info[:, index, :, index, :] += np.swapaxes(prior_information(prior_cov), 0, 1)
    return np.swapaxes(info.reshape(c, size, size), 1, 2)  # the same (symmetric) matrix, column-major: LAPACK's order


# The entries an observation i -> j adds (``fisher_informations``), one column each: the block (0: (i, i), 1: (j, j),
# 2: (i, j), 3: (j, i)), the entry within it (3 row + column; rows and columns x, y, heading) and the term (0-5: A_xx,
# A_xy, A_yy, h_x, h_y, 1 / s_b^2; 6-11: the same negated).
_ENTRIES = tuple(np.array(part) for part in zip(
    *[(0, 3 * a + b, (0, 1, 2)[a + b]) for a in (0, 1) for b in (0, 1)],  # I[p_i, p_i] += A
    *[(0, 3 * a + 2, 3 + a) for a in (0, 1)], *[(0, 6 + a, 3 + a) for a in (0, 1)],  # I[theta_i, p_i] += h^T (and its mirror)
    (0, 8, 5),  # I[theta_i, theta_i] += 1 / s_b^2
    *[(1, 3 * a + b, (0, 1, 2)[a + b]) for a in (0, 1) for b in (0, 1)],  # I[p_j, p_j] += A
    *[(2, 3 * a + b, 6 + (0, 1, 2)[a + b]) for a in (0, 1) for b in (0, 1)],  # I[p_i, p_j] -= A
    *[(3, 3 * a + b, 6 + (0, 1, 2)[a + b]) for a in (0, 1) for b in (0, 1)],  # I[p_j, p_i] -= A
    *[(2, 6 + a, 9 + a) for a in (0, 1)], *[(3, 3 * a + 2, 9 + a) for a in (0, 1)],  # I[theta_i, p_j] -= h^T (and its mirror)
    strict=True,
))


def fisher_information(
    true_poses: np.ndarray, prior_cov: np.ndarray, observer_idx: np.ndarray, observed_idx: np.ndarray, cfg: ModelConfig
) -> np.ndarray:
    """Dense Fisher information (3n, 3n) = J^T J of the whitened prior + observation residuals at ``true_poses``
    (``fisher_informations`` of one swarm)."""
    poses = np.asarray(true_poses, dtype=float)
    observer_idx = np.asarray(observer_idx, dtype=np.int64)
    observed_idx = np.asarray(observed_idx, dtype=np.int64)
    swarm = np.zeros(len(observer_idx), np.int64)
    return np.asarray(fisher_informations(poses[None], np.asarray(prior_cov, dtype=float)[None], swarm, observer_idx, observed_idx, cfg)[0])


def crlb_pose_covariances(
    true_poses: np.ndarray, prior_cov: np.ndarray, observer_idx: np.ndarray, observed_idx: np.ndarray, cfg: ModelConfig
) -> np.ndarray:
    """Per-robot CRLB covariances (n, 3, 3): the 3x3 diagonal blocks of the inverse Fisher information.

    ``prior_cov`` (n, 3, 3) is the dead-reckoning covariance; ``observer_idx`` and
    ``observed_idx`` index rows of ``true_poses`` (n, 3). Dense inverse: meant for
    benchmarks up to ~1000 robots.
    """
    n = len(true_poses)
    full = np.linalg.inv(fisher_information(true_poses, prior_cov, observer_idx, observed_idx, cfg))
    idx = np.arange(3 * n).reshape(n, 3)
    cov = full[idx[:, :, None], idx[:, None, :]]
    return 0.5 * (cov + np.swapaxes(cov, -1, -2))
