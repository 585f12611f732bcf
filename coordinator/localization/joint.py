"""Joint weighted least squares over dead-reckoning priors and all observations.

The Graph-SLAM-like alternative discussed in Section 5.3: instead of clustering the
observations (Phase 1.2) and then superimposing (Phase 2), all robot poses are solved
at once, minimising the whitened prior residuals of the dead-reckoning estimate
(mean and 3x3 covariance from Phase 1.1) plus the whitened range and bearing
residuals of every observation. Sparse Levenberg-Marquardt (``sparse_lm``).

Uncertainty: the joint covariance (J^T J)^-1 of all poses is returned (``SwarmEstimate.joint``)
up to ``EXACT_COV_LIMIT`` robots, and when the prior carries it, the dead-reckoning prior
is whitened with the full joint covariance (not per robot): the next step then sees the
cross-correlations the previous steps built, which keeps the reported covariance honest
along a trajectory (an iterated extended Kalman filter; docs/localization.md).
The marginal covariances are the 3x3 diagonal blocks of (J^T J)^-1.
Up to ``EXACT_COV_LIMIT`` robots they are exact; above it, the blocks of the
information matrix are inverted on their own (conditional covariances, which
are optimistic) to keep a 1000-robot step well under a second. Every block is
projected onto the positive semi-definite cone (``psd``), so rounding never
yields a negative variance.

No convergence: the error names the robots of the observation with the largest
whitened residual at the last iterate, the likeliest culprits, so that
``partial.localize_observable`` can localize the others without them.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from coordinator.localization.dead_reckoning import dead_reckon_parts
from coordinator.localization.graph import require_observable
from coordinator.localization.paper import PaperLocalizer
from coordinator.localization.range_bearing import (
    joint_prior_terms,
    joint_sqrt_information,
    observation_terms,
    prior_terms,
    sqrt_information,
    stack_terms,
)
from coordinator.localization.sparse_lm import PoseLayout, blas_threads, dense, levenberg_marquardt
from coordinator.localization.topology import Topology
from runtime.config import ModelConfig
from runtime.errors import LocalizationError
from runtime.geometry import wrap_angle
from runtime.state import Observations, StepCommands, SwarmEstimate

EXACT_COV_LIMIT = 500  # robots


def psd(cov: np.ndarray) -> np.ndarray:
    """Nearest symmetric positive semi-definite matrices (..., k, k) (negative eigenvalues set to 0).

    Non-finite matrices (a singular information matrix) raise ``LocalizationError("degenerate")``
    at the caller; here they are returned as they are.
    """
    sym = 0.5 * (cov + np.swapaxes(cov, -1, -2))
    out = sym.copy()
    suspect = np.isfinite(sym).all(axis=(-2, -1)) & ~_positive_definite(sym)
    if suspect.any():
        lam, vec = np.linalg.eigh(sym[suspect])
        out[suspect] = (vec * np.maximum(lam, 0.0)[..., None, :]) @ np.swapaxes(vec, -1, -2)
    return out


def _positive_definite(sym: np.ndarray) -> np.ndarray:
    """(...,) True where the symmetric matrices are clearly positive definite (cheap test: 3x3 Sylvester, else Cholesky)."""
    if sym.shape[-1] == 3:
        a, b, c, d, e, f = sym[..., 0, 0], sym[..., 1, 1], sym[..., 2, 2], sym[..., 0, 1], sym[..., 0, 2], sym[..., 1, 2]
        det = a * (b * c - f * f) - d * (d * c - f * e) + e * (d * f - b * e)
        with np.errstate(invalid="ignore"):
            return (a > 0) & (a * b - d * d > 0) & (det > 0)
    out = np.zeros(sym.shape[:-2], bool)
    for k in np.ndindex(out.shape):
        try:
            np.linalg.cholesky(sym[k])
            out[k] = True
        except np.linalg.LinAlgError:
            pass
    return out


def pose_covariances(normal: sp.csr_matrix, layout: PoseLayout, n_robots: int) -> np.ndarray:
    """3x3 pose covariances (n, 3, 3) from the information matrix; fixed components get 0."""
    cols = layout.cols
    free = cols >= 0
    safe = np.where(free, cols, 0)
    if n_robots <= EXACT_COV_LIMIT:
        try:
            full = np.linalg.inv(dense(normal))
        except np.linalg.LinAlgError:  # singular: reported as degenerate by ``checked``
            full = np.full(normal.shape, np.nan)
        cov = full[safe[:, :, None], safe[:, None, :]]
    else:
        rows, cols_ = safe[:, :, None].repeat(3, 2).ravel(), safe[:, None, :].repeat(3, 1).ravel()
        blocks = normal[rows, cols_] if isinstance(normal, np.ndarray) else np.asarray(normal.tocsr()[rows, cols_])
        blocks = blocks.reshape(n_robots, 3, 3)
        pair_free = free[:, :, None] & free[:, None, :]
        blocks = np.where(pair_free, blocks, np.eye(3))  # fixed components: identity, zeroed below
        try:
            cov = np.linalg.inv(blocks)
        except np.linalg.LinAlgError:
            cov = np.full(blocks.shape, np.nan)
    return psd(cov * (free[:, :, None] & free[:, None, :]))


def joint_covariance(normal: sp.spmatrix | np.ndarray) -> np.ndarray:
    """(J^T J)^-1 (3n, 3n), symmetric and positive semi-definite; NaN where singular."""
    try:
        full = np.linalg.inv(dense(normal))
    except np.linalg.LinAlgError:
        return np.full(normal.shape, np.nan)
    full = 0.5 * (full + full.T)
    if not np.isfinite(full).all():
        return full
    try:
        np.linalg.cholesky(full)
        return full
    except np.linalg.LinAlgError:
        return psd(full)


def worst_observation(residual: np.ndarray, observer: np.ndarray, observed: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """Ids of the two robots of the observation with the largest whitened residual (range^2 + bearing^2)."""
    if len(observer) == 0:
        return ids
    per_obs = residual[-2 * len(observer) :].reshape(-1, 2)
    k = int(np.argmax(np.sum(per_obs**2, axis=1)))
    return ids[[observer[k], observed[k]]]


def checked(cov: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """``cov`` if every entry is finite, else ``LocalizationError("degenerate")`` naming the robots concerned."""
    bad = ~np.isfinite(cov).all(axis=(1, 2))
    if bad.any():
        raise LocalizationError("degenerate", ids[bad], "the information matrix is singular for them")
    return cov


class JointLocalizer:
    """All poses at once: whitened dead-reckoning priors + range/bearing observations."""

    name = "joint"

    def __init__(self, cfg: ModelConfig, huber: float | None = None) -> None:
        self.cfg = cfg
        self.huber = huber  # in sigmas of the whitened residuals; None = least squares

    def localize(self, prior: SwarmEstimate, step: StepCommands, obs: Observations) -> SwarmEstimate:
        with blas_threads(3 * prior.n):
            return self._localize(prior, step, obs)

    def _localize(self, prior: SwarmEstimate, step: StepCommands, obs: Observations) -> SwarmEstimate:
        mean, dr_cov, dr_joint = dead_reckon_parts(prior, step, self.cfg)  # arrays: no re-validation
        i, j = obs.indexed(prior.ids)
        require_observable(prior.ids, i, j)
        n = prior.n
        layout = PoseLayout(np.ones(n, bool), np.ones(n, bool))
        carried = dr_joint is not None and n <= EXACT_COV_LIMIT
        u = joint_sqrt_information(dr_joint) if carried else sqrt_information(dr_cov)
        prior_fn = joint_prior_terms if carried else prior_terms

        def residuals(vec: np.ndarray) -> tuple[np.ndarray, sp.csr_matrix]:
            poses = layout.unpack(vec, mean)
            return stack_terms(
                layout.size,
                prior_fn(poses, layout, mean, u),
                observation_terms(poses, layout, i, j, obs.range_m, obs.bearing_rad, self.cfg),
            )

        result = levenberg_marquardt(residuals, layout.pack(mean), huber=self.huber)
        if not result.converged:
            suspects = worst_observation(residuals(result.x)[0], i, j, prior.ids)
            raise LocalizationError("no-convergence", suspects, "joint least squares did not converge")
        poses = layout.unpack(result.x, mean)
        poses[:, 2] = wrap_angle(poses[:, 2])
        if n > EXACT_COV_LIMIT:
            return SwarmEstimate(prior.ids, poses, checked(pose_covariances(result.normal_matrix, layout, n), prior.ids))
        joint = joint_covariance(result.normal_matrix)
        idx = np.arange(3 * n).reshape(n, 3)
        checked(joint[idx[:, :, None], idx[:, None, :]], prior.ids)
        return SwarmEstimate.from_joint(prior.ids, poses, joint)

    def topology(self, ids: np.ndarray, obs: Observations, initial_poses: np.ndarray | None = None) -> Topology:
        """Relative poses with no prior, gauge as in the paper's topology (reference robot at the origin).

        Started from the paper's topology, refined on the whitened range/bearing residuals;
        delta_p is the marginal position uncertainty relative to the reference robot.
        """
        ids = np.asarray(ids, dtype=np.int64)
        start = PaperLocalizer(self.cfg).topology(ids, obs, initial_poses)
        i, j = obs.indexed(ids)
        n = len(ids)
        has_heading = np.isfinite(start.headings)
        free = np.arange(n) != start.reference
        layout = PoseLayout(free, free & has_heading)
        base = np.column_stack([start.solved_positions, np.where(has_heading, start.headings, 0.0)])

        def residuals(vec: np.ndarray) -> tuple[np.ndarray, sp.csr_matrix]:
            poses = layout.unpack(vec, base)
            return stack_terms(layout.size, observation_terms(poses, layout, i, j, obs.range_m, obs.bearing_rad, self.cfg))

        result = levenberg_marquardt(residuals, layout.pack(base), huber=self.huber)
        if not result.converged:
            suspects = worst_observation(residuals(result.x)[0], i, j, ids)
            raise LocalizationError("no-convergence", suspects, "joint topology did not converge")
        poses = layout.unpack(result.x, base)
        cov = checked(pose_covariances(result.normal_matrix, layout, n), ids)
        delta = np.sqrt(cov[:, 0, 0] + cov[:, 1, 1])
        heading_sigma = np.where(has_heading, np.sqrt(cov[:, 2, 2]), np.inf)
        headings = np.where(has_heading, wrap_angle(poses[:, 2]), np.nan)
        return Topology(poses[:, :2], poses[:, :2].copy(), headings, delta, heading_sigma, start.reference)
