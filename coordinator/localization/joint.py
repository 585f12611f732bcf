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

from typing import cast

import numpy as np
import scipy.sparse as sp

from coordinator.localization.dead_reckoning import dead_reckon_parts
from coordinator.localization.gauge import constrained_covariance, constrained_solution, gauge_frame, inverse, merge_subset, transport
from coordinator.localization.graph import require_observable
from coordinator.localization.joint_normal import JointProblem
from coordinator.localization.paper import PaperLocalizer
from coordinator.localization.range_bearing import joint_sqrt_information, observation_terms, sqrt_information, stack_terms
from coordinator.localization.sparse_lm import PoseLayout, blas_threads, levenberg_marquardt, minimize
from coordinator.localization.superimpose import weighted_procrustes
from coordinator.localization.topology import Topology
from runtime.errors import LocalizationError
from runtime.models.config import ModelConfig
from runtime.models.geometry import rotate, wrap_angle
from runtime.models.state import Observations, StepCommands, SwarmEstimate

EXACT_COV_LIMIT = 500  # robots
# Convergence of the joint solve: a step below 1e-8 of (1 + |x|) or a relative cost decrease below 1e-8.
# The cost is a sum of whitened squares, so stopping there leaves the solution ~1e-4 sigma from the exact
# minimum (sparse_lm's 1e-10 / 1e-12 took 2-3 more factorizations for digits no one can use; GTSAM's
# Levenberg-Marquardt stops at a relative decrease of 1e-5).
XTOL, FTOL = 1e-8, 1e-8
# ... and stops before a step whose Gauss-Newton model predicts a decrease below 1e-6 of the cost
# (``sparse_lm.minimize``'s ptol): the solution is then within ~sqrt(2e-6 cost) whitened units of the
# minimum, about 0.01 sigma over a 10-robot swarm, and the last one or two evaluations are saved.
PTOL = 1e-6
# A solution whose cost (half the sum of whitened squares) is implausible for its 2 m observation residuals is a
# wrong local minimum: the solve is run again from the observations' own configuration (``rescue_start``).
# Threshold: the chi-square(2 m) quantile at 1 - 1e-6 (Wilson-Hilferty), so a consistent step triggers it about once
# in a million; a wrong minimum (a mover's heading tens of degrees off) has a cost of thousands.
RESCUE_Z = 4.75  # standard normal quantile at 1 - 1e-6


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
    return cast(np.ndarray, out)


def _positive_definite(sym: np.ndarray) -> np.ndarray:
    """(...,) True where the symmetric matrices are clearly positive definite (cheap test: 3x3 Sylvester, else Cholesky)."""
    if sym.shape[-1] == 3:
        a, b, c, d, e, f = sym[..., 0, 0], sym[..., 1, 1], sym[..., 2, 2], sym[..., 0, 1], sym[..., 0, 2], sym[..., 1, 2]
        det = a * (b * c - f * f) - d * (d * c - f * e) + e * (d * f - b * e)
        with np.errstate(invalid="ignore"):
            return cast(np.ndarray, (a > 0) & (a * b - d * d > 0) & (det > 0))
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
        cov = inverse(normal)[safe[:, :, None], safe[:, None, :]]  # NaN where singular: ``checked`` names them
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


def psd_joint(cov: np.ndarray) -> np.ndarray:
    """``cov`` (k, k) symmetrized, projected onto the PSD cone only when its Cholesky factorization fails."""
    full = 0.5 * (cov + cov.T)
    if not np.isfinite(full).all():
        return cast(np.ndarray, full)
    try:
        np.linalg.cholesky(full)
        return cast(np.ndarray, full)
    except np.linalg.LinAlgError:
        return psd(full)


def block_diagonal(cov: np.ndarray) -> np.ndarray:
    """The joint covariance (3n, 3n) of independent robots with covariances ``cov`` (n, 3, 3)."""
    n = len(cov)
    out = np.zeros((n, 3, n, 3))
    out[np.arange(n), :, np.arange(n), :] = cov
    return out.reshape(3 * n, 3 * n)


def _rows(keep: np.ndarray) -> np.ndarray:
    """Indices of the state components (x, y, heading) of the robots where ``keep`` (n,)."""
    return (3 * np.flatnonzero(keep)[:, None] + np.arange(3)).ravel()


def worst_observation(residual: np.ndarray, observer: np.ndarray, observed: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """Ids of the two robots of the observation with the largest whitened residual (range^2 + bearing^2).

    ``residual`` holds the observations' whitened residuals, (m, 2) or flat and last in the vector.
    """
    if len(observer) == 0:
        return ids
    per_obs = residual.reshape(-1)[-2 * len(observer) :].reshape(-1, 2)
    k = int(np.argmax(np.sum(per_obs**2, axis=1)))
    return ids[[observer[k], observed[k]]]


def implausible(cost: np.ndarray | float, observations: np.ndarray | int) -> np.ndarray:
    """Whether a solution's ``cost`` (half its sum of whitened squares) is beyond the chi-square quantile of
    2 ``observations`` residuals at 1 - 1e-6 (Wilson-Hilferty's approximation), elementwise."""
    k = np.maximum(2.0 * np.asarray(observations, dtype=float), 1.0)
    a = 2.0 / (9.0 * k)
    return np.asarray(2.0 * np.asarray(cost) > k * (1.0 - a + RESCUE_Z * np.sqrt(a)) ** 3)


def rescue_start(cfg: ModelConfig, ids: np.ndarray, obs: Observations, mean: np.ndarray, cov: np.ndarray) -> np.ndarray | None:
    """A start (k, 3) for the joint solve from the observations alone: the joint topology (no prior; the paper's topology
    from the linear relaxation, refined) superimposed on the dead reckoning ``mean`` (k, 3) by weighted Procrustes
    (weights 1 / the trace of each position covariance ``cov`` (k, 3, 3)); a robot without a topology heading keeps its
    dead-reckoned one, headings are unwrapped about ``mean``'s. None where the topology cannot be solved."""
    try:
        topo = JointLocalizer(cfg).topology(ids, obs)
    except LocalizationError:
        return None
    w = 1.0 / np.maximum(cov[:, 0, 0] + cov[:, 1, 1], 1e-12)
    theta, t, _ = weighted_procrustes(topo.solved_positions, mean[:, :2], w)
    heading = np.where(np.isfinite(topo.headings), np.nan_to_num(topo.headings) + theta, mean[:, 2])
    return np.column_stack([rotate(theta, topo.solved_positions) + t, mean[:, 2] + wrap_angle(heading - mean[:, 2])])


def checked(cov: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """``cov`` if every entry is finite, else ``LocalizationError("degenerate")`` naming the robots concerned."""
    bad = ~np.isfinite(cov).all(axis=(1, 2))
    if bad.any():
        raise LocalizationError("degenerate", ids[bad], "the information matrix is singular for them")
    return cov


class JointLocalizer:
    """All poses at once: whitened dead-reckoning priors + range/bearing observations."""

    name = "joint"
    exact_motion = True  # dead reckoning with the exact moments of the motion (``motion.motion_moments``)

    def __init__(self, cfg: ModelConfig, huber: float | None = None, constrain_gauge: bool = True) -> None:
        self.cfg = cfg
        self.huber = huber  # in sigmas of the whitened residuals; None = least squares
        self.constrain_gauge = constrain_gauge  # observability-constrained joint covariance (``gauge``)

    def localize(self, prior: SwarmEstimate, step: StepCommands, obs: Observations) -> SwarmEstimate:
        return self.localize_subset(prior, step, obs, np.ones(prior.n, bool))

    def localize_subset(self, prior: SwarmEstimate, step: StepCommands, obs: Observations, keep: np.ndarray) -> SwarmEstimate:
        """Post-step estimate of the whole swarm, localizing the robots where ``keep`` (n,) from the
        observations among them; the others keep their dead reckoning (``partial.localize_observable``).

        Up to ``EXACT_COV_LIMIT`` robots the joint covariance is returned: observability-constrained,
        the others' cross-covariances updated with the kept robots' (``gauge``), and the poses are those
        of the constrained update (``gauge.constrained_solution``). Above it, the least-squares poses and
        the conditional 3x3 blocks only.
        """
        keep = np.asarray(keep, bool)
        with blas_threads(3 * prior.n):
            mean, dr_cov, dr_joint = dead_reckon_parts(prior, step, self.cfg, self.exact_motion)  # arrays: no re-validation
            exact = prior.n <= EXACT_COV_LIMIT
            i, j = obs.indexed(prior.ids)
            if keep.all():  # the whole swarm: one gauge frame serves the constrained covariance and its transport
                sub_obs, index, frame = obs, (i, j), gauge_frame(mean) if exact and self.constrain_gauge else None
            else:
                sub_obs, index, frame = obs.select(keep[i] & keep[j]), None, None
            sub_joint = None if dr_joint is None or not exact else dr_joint[np.ix_(_rows(keep), _rows(keep))]
            poses_a, cov_a = self._solve(prior.ids[keep], mean[keep], dr_cov[keep], sub_joint, sub_obs, exact, index, frame)
            if exact and dr_joint is None and not keep.all():  # independent robots (a first step): sparse prior above
                dr_joint = block_diagonal(dr_cov)
            poses = mean.copy()
            poses[keep] = poses_a
            if not exact:
                cov = dr_cov.copy()
                cov[keep] = cov_a
                poses[:, 2] = wrap_angle(poses[:, 2])
                return SwarmEstimate(prior.ids, poses, cov)
            joint = merge_subset(dr_joint, cov_a, keep)
            joint = psd_joint(transport(joint, mean, poses, frame) if self.constrain_gauge else joint)
            poses[:, 2] = wrap_angle(poses[:, 2])
            idx = _rows(np.ones(prior.n, bool)).reshape(prior.n, 3)
            checked(joint[idx[:, :, None], idx[:, None, :]], prior.ids)
            return SwarmEstimate.derived(prior, poses, joint)

    def _solve(
        self,
        ids: np.ndarray,
        mean: np.ndarray,
        cov: np.ndarray,
        joint: np.ndarray | None,
        obs: Observations,
        exact: bool,
        index: tuple[np.ndarray, np.ndarray] | None = None,
        frame: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Poses (k, 3, headings unwrapped) of robots ``ids`` and their covariance: the joint one (3k, 3k) when
        ``exact``, else conditional 3x3 blocks (k, 3, 3). With ``constrain_gauge`` and ``exact`` both are the
        observability-constrained update's (covariance before ``transport``), else the least-squares solution's.

        The prior is the dead reckoning: ``mean`` (k, 3) with its joint covariance when given
        (whitened with its Cholesky factor), else the per-robot ``cov`` (k, 3, 3). ``index``: the observations'
        (observer, observed) indices into ``ids`` when the caller has them; ``frame``: ``gauge.gauge_frame(mean)``
        when the caller has it.
        """
        i, j = obs.indexed(ids) if index is None else index
        require_observable(ids, i, j, headings_known=True)  # the prior fixes every heading
        n = len(ids)
        u = sqrt_information(cov) if joint is None else joint_sqrt_information(joint)
        problem = JointProblem(mean, u, i, j, obs.range_m, obs.bearing_rad, self.cfg, self.huber)
        result = minimize(problem.evaluate, mean.ravel(), solve=problem.solve, xtol=XTOL, ftol=FTOL, ptol=PTOL)
        if result.converged and implausible(result.cost, len(i)):  # a wrong local minimum: start from the observations
            start = rescue_start(self.cfg, ids, obs, mean, cov)
            again = None if start is None else minimize(problem.evaluate, start.ravel(), solve=problem.solve, xtol=XTOL, ftol=FTOL, ptol=PTOL)
            if again is not None and again.converged and again.cost < result.cost:
                result = again
        if not result.converged:
            suspects = worst_observation(problem.residuals(result.x)[1], i, j, ids)
            raise LocalizationError("no-convergence", suspects, "joint least squares did not converge")
        poses = result.x.reshape(n, 3).copy()
        if not exact:
            return poses, checked(pose_covariances(result.normal_matrix, PoseLayout(np.ones(n, bool), np.ones(n, bool)), n), ids)
        if self.constrain_gauge:
            frame = gauge_frame(mean) if frame is None else frame  # shared by the covariance and the estimate
            cov = constrained_covariance(result.normal_matrix, problem.observation_normal(cast(np.ndarray, result.extra)), mean, frame)
            poses = constrained_solution(poses, mean, cov, problem.prior_gradient(result.x), frame)
        else:
            cov = inverse(result.normal_matrix)
        if not np.isfinite(cov).all():  # singular information: name the robots through their blocks
            blocks = _rows(np.ones(n, bool)).reshape(n, 3)
            checked(cov[blocks[:, :, None], blocks[:, None, :]], ids)
        return poses, cov

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
