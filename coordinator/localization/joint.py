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

from coordinator.localization.dead_reckoning import dead_reckon
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
    finite = np.isfinite(sym).all(axis=(-2, -1))
    out = sym.copy()
    if finite.any():
        lam, vec = np.linalg.eigh(sym[finite])
        if (lam < 0).any():
            out[finite] = (vec * np.maximum(lam, 0.0)[..., None, :]) @ np.swapaxes(vec, -1, -2)
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


def gauge_basis(poses: np.ndarray, members: np.ndarray | None = None) -> np.ndarray:
    """(..., 3n, 3) orthonormal basis of the motions of the whole swarm that no observation sees.

    Translating every robot, and rotating the swarm (positions about the origin and every
    heading by the same angle), changes no range or bearing: at poses p (..., n, 3) these
    directions are (1, 0, 0)_i, (0, 1, 0)_i and ``rotation_direction(p)``, over the robots
    where ``members`` (..., n) (default all: the observed group; others do not move with it).
    """
    basis = _gauge_directions(poses, members)
    return np.linalg.qr(basis)[0]


def _gauge_directions(poses: np.ndarray, members: np.ndarray | None = None) -> np.ndarray:
    """(..., 3n, 3): x translation, y translation, rotation about the origin at ``poses`` of the ``members``."""
    shape = poses.shape[:-2]
    n = poses.shape[-2]
    basis = np.zeros(shape + (n, 3, 3))
    basis[..., 0, 0] = basis[..., 1, 1] = 1.0
    basis[..., 2] = rotation_direction(poses).reshape(shape + (n, 3))
    if members is not None:
        basis *= members[..., None, None]
    return basis.reshape(shape + (3 * n, 3))


def rotation_direction(poses: np.ndarray) -> np.ndarray:
    """(..., 3n) the swarm's rotation about the origin at ``poses`` (..., n, 3): (-y_i, x_i, 1) per robot."""
    out = np.stack([-poses[..., 1], poses[..., 0], np.ones(poses.shape[:-1])], axis=-1)
    return out.reshape(poses.shape[:-2] + (-1,))


def constrained_information(obs_info: np.ndarray, predicted: np.ndarray, members: np.ndarray | None = None) -> np.ndarray:
    """Observation information J^T J (..., 3n, 3n) with the gauge directions of ``predicted`` poses removed.

    J is evaluated at the solution, whose own gauge directions J annihilates, but the prior's
    covariance was built around the predicted (dead-reckoning) poses. Without this projection
    the observations would seem to inform the swarm's global rotation (the direction the prior
    holds at the predicted poses), spurious information that makes an extended Kalman filter
    overconfident along a trajectory; projecting the Jacobian onto the complement of those
    directions (observability-constrained EKF) leaves the global pose to the prior.
    """
    q = gauge_basis(predicted, members)
    qt = np.swapaxes(q, -1, -2)
    aq = obs_info @ q
    return obs_info - aq @ qt - q @ np.swapaxes(aq, -1, -2) + q @ (qt @ aq) @ qt


def transport_gauge(
    joint: np.ndarray, predicted: np.ndarray, solved: np.ndarray, members: np.ndarray | None = None
) -> np.ndarray:
    """``joint`` (..., 3n, 3n) with its rotation gauge moved from the predicted poses to the solution.

    The covariance's unobservable rotation was built around ``predicted`` poses; the next step
    linearises at ``solved``, whose rotation direction differs by the correction (-dy_i, dx_i, 0).
    Left as is, the next prior would look more certain along the new direction than along the
    old one (spurious information on the global rotation, compounding along a trajectory).
    T = I + (r_solved - r_predicted) g^T, with g the dual of r_predicted in the gauge basis
    (g^T r_predicted = 1, g^T translations = 0), maps the old direction onto the new one and
    leaves translations alone; the covariance becomes T P T^T (first estimates, as in an
    observability-constrained EKF). Non-finite matrices are returned as they are.
    """
    finite = np.isfinite(joint).all(axis=(-2, -1))
    basis = _gauge_directions(predicted, members)
    dual = np.linalg.pinv(basis)[..., 2, :]  # g: g^T basis = (0, 0, 1)
    d = _gauge_directions(solved, members)[..., 2] - basis[..., 2]
    safe = np.where(finite[..., None, None], joint, 0.0)
    t_p = safe + d[..., :, None] * (dual[..., None, :] @ safe)  # T P
    out = t_p + (t_p @ dual[..., :, None]) * d[..., None, :]  # T P T^T
    out = 0.5 * (out + np.swapaxes(out, -1, -2))
    return np.where(finite[..., None, None], out, joint)


def _block_diag(blocks: np.ndarray) -> np.ndarray:
    """Dense block-diagonal matrix (3n, 3n) from (n, 3, 3) blocks."""
    n = len(blocks)
    out = np.zeros((n, 3, n, 3))
    out[np.arange(n), :, np.arange(n), :] = blocks
    return out.reshape(3 * n, 3 * n)


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
        dr = dead_reckon(prior, step, self.cfg)
        i, j = obs.indexed(prior.ids)
        require_observable(prior.ids, i, j)
        n = prior.n
        layout = PoseLayout(np.ones(n, bool), np.ones(n, bool))
        mean = dr.poses
        carried = dr.joint is not None and n <= EXACT_COV_LIMIT
        u = joint_sqrt_information(dr.joint) if carried else sqrt_information(dr.cov)
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
        prior_info = u.T @ u if carried else _block_diag(np.swapaxes(u, 1, 2) @ u)
        _, obs_jac = stack_terms(layout.size, observation_terms(poses, layout, i, j, obs.range_m, obs.bearing_rad, self.cfg))
        obs_info = constrained_information(dense(obs_jac.T @ obs_jac), mean)
        joint = transport_gauge(joint_covariance(prior_info + obs_info), mean, poses)
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
