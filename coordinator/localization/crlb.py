"""Cramer-Rao lower bound of one localization step (benchmark reference).

The post-step poses p (n robots x (x, y, heading)) are estimated from

* the dead-reckoning prior p ~ N(mu, P_i) per robot (Phase 1.1: the pre-step
  estimate moved by the commands, with the propagated 3x3 covariance), and
* the range/bearing observations (Eq. 20) with noise N(0, s_r), N(0, s_b).

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

from coordinator.localization.range_bearing import observation_terms, prior_terms, sqrt_information, stack_terms
from coordinator.localization.sparse_lm import PoseLayout, dense
from runtime.models.config import ModelConfig


def fisher_information(
    true_poses: np.ndarray, prior_cov: np.ndarray, observer_idx: np.ndarray, observed_idx: np.ndarray, cfg: ModelConfig
) -> np.ndarray:
    """Dense Fisher information (3n, 3n) = J^T J of the whitened prior + observation residuals at ``true_poses``."""
    poses = np.asarray(true_poses, dtype=float)
    n = len(poses)
    layout = PoseLayout(np.ones(n, bool), np.ones(n, bool))
    observer_idx = np.asarray(observer_idx, dtype=np.int64)
    observed_idx = np.asarray(observed_idx, dtype=np.int64)
    # Only the Jacobian matters (measured values and prior mean just shift the residuals), and the
    # bearing weights, which depend on the range: the true one here.
    d = poses[observed_idx, :2] - poses[observer_idx, :2]
    rho = np.hypot(d[:, 0], d[:, 1])
    _, jac = stack_terms(
        layout.size,
        prior_terms(poses, layout, poses, sqrt_information(np.asarray(prior_cov, dtype=float))),
        observation_terms(poses, layout, observer_idx, observed_idx, rho, np.zeros(len(rho)), cfg),
    )
    return dense(jac.T @ jac)


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

