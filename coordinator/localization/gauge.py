"""The swarm's global pose is unobservable: keep the joint covariance from pretending otherwise.

Range and body-frame bearing observations between robots are blind to three directions of
the joint state, the gauge: a global translation (x, y) and a global rotation of every pose
(``gauge_basis``). Only the first prior and the dead reckoning fix them, so a consistent
filter never gains information along them. An extended Kalman filter does: its prior's
information has no observation information along the gauge at the predicted poses N(mu),
but the observation Jacobian H of an update, evaluated at the solution, is blind to
N(solution) instead, and adding H^T H gains a little spurious information on the global
rotation at every step. Along a trajectory the reported covariance then shrinks far below the
error (measured: position NEES 2-8 x its expected value after 100 configurations).

Observability-constrained covariance (Huang, Mourikis & Roumeliotis, "Observability-based
rules for designing consistent EKF SLAM estimators", IJRR 2010), four pieces:

* ``constrained_covariance``: the observation rows are projected off N(mu),
  H~ = H (I - N (N^T N)^-1 N^T), and the covariance is (J^T J - H^T H + H~^T H~)^-1.
* ``constrained_solution``: the estimate is moved to where the update with H~ puts it (one Gauss-Newton step from
  the least-squares solution): its gauge component no longer follows the spurious information either.
* ``merge_subset``: when only some robots were localized (the others keep dead reckoning),
  their cross-covariance with the others follows the same linear update (positive
  semi-definite by construction).
* ``transport``: the covariance is moved from N(mu) to N(solution), T = I + (N(solution) -
  N(mu)) (N^T N)^-1 N^T, where the next step's propagation (linearised at the solution) maps
  N(solution) onto the next prediction's gauge directions exactly.

Units: metres and radians; matrices are ordered robot by robot (x_0, y_0, heading_0, x_1, ...).
"""

from __future__ import annotations

import functools
from typing import cast

import numpy as np
import scipy.sparse as sp
from scipy.linalg.lapack import dpotrf, dpotri

from coordinator.localization.sparse_lm import BLAS_SMALL, blas_threads, dense

_ROTATION = np.array([0.0, 0.0, 1.0])  # the rotation's share of N^T N


def gauge_basis(poses: np.ndarray, center: np.ndarray | None = None, keep: np.ndarray | None = None) -> np.ndarray:
    """N (..., 3n, 3): the swarm's global translation (x, y) and rotation about ``center`` (..., 2) (default: the
    centroid) at ``poses`` (..., n, 3), one swarm or a batch. ``keep`` (..., n): only these robots move (the other
    rows are zero: the gauge of a subset, in the whole swarm's coordinates).

    Relative range and bearing observations do not change along these directions, to first
    order at ``poses``: H(poses) N = 0.
    """
    n = poses.shape[-2]
    c = poses[..., :2] - (poses[..., :2].mean(axis=-2) if center is None else center)[..., None, :]
    basis = np.zeros(poses.shape[:-1] + (3, 3))
    basis[..., 0, 0] = basis[..., 1, 1] = basis[..., 2, 2] = 1.0
    basis[..., 0, 2], basis[..., 1, 2] = -c[..., 1], c[..., 0]
    if keep is not None:
        basis *= keep[..., None, None]
    return basis.reshape(poses.shape[:-2] + (3 * n, 3))


def gauge_frame(predicted: np.ndarray, keep: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(N, Pi = (N^T N)^-1 N^T) at the predicted poses (..., n, 3), rotation about their centroid (Pi gives the
    coordinates along N of a state vector): what ``gauge_correction`` and ``transport`` of one update share
    (computed once per step). ``keep`` (..., n): the gauge of these robots alone (rotation about their centroid;
    the others' rows of N and columns of Pi are zero)."""
    if keep is None:
        count: float | np.ndarray = float(predicted.shape[-2])
        center = predicted[..., :2].mean(axis=-2)
    else:
        kept = np.maximum(keep.sum(axis=-1), 1).astype(float)  # none kept: a zero frame
        center = np.einsum("...n,...nk->...k", keep, predicted[..., :2]) / kept[..., None]
        count = kept
    basis = gauge_basis(predicted, center, keep)
    # About the centroid the offsets c_i sum to zero, so N^T N = diag(k, k, k + sum |c_i|^2): no solve.
    offsets = np.sum(basis[..., 0::3, 2] ** 2 + basis[..., 1::3, 2] ** 2, axis=-1)  # sum |c_i|^2 (rotation column: (-c_y, c_x))
    scale = np.asarray(count)[..., None] + offsets[..., None] * _ROTATION
    return basis, np.swapaxes(basis, -1, -2) / scale[..., :, None]


def gauge_correction(observed_basis: np.ndarray, frame: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """(U (..., 3n, 6), K (..., 6, 6)) with H~^T H~ - H^T H = U K U^T, H~ = H projected off the predicted gauge.

    ``observed_basis`` is S N (..., 3n, 3), S = H^T H the observations' (whitened) information, N and
    Pi = (N^T N)^-1 N^T from ``frame``: H~^T H~ = S - S N Pi - (S N Pi)^T + Pi^T (N^T S N) Pi, a correction of
    rank <= 6: U = [S N, Pi^T], K = [[0, -I], [-I, N^T S N]] (symmetric). The one definition of the constraint,
    for one swarm (``constrained_covariance``) and the planner's batch (``batch``, through the Woodbury identity).
    """
    basis, proj = frame
    u = np.concatenate([observed_basis, np.swapaxes(proj, -1, -2)], axis=-1)
    k = np.zeros(observed_basis.shape[:-2] + (6, 6))
    k[..., :3, 3:] = k[..., 3:, :3] = -np.eye(3)
    k[..., 3:, 3:] = np.swapaxes(basis, -1, -2) @ observed_basis
    return u, k


def constrained_covariance(
    normal: sp.spmatrix | np.ndarray,
    observed: sp.spmatrix | np.ndarray,
    predicted: np.ndarray,
    frame: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """(J^T J - H^T H + H~^T H~)^-1 (3n, 3n), H~ = H projected off N(``predicted``); NaN where singular.

    ``normal`` is J^T J at the solution (whitened prior and observations), ``observed`` the
    observations' share H^T H of it (whitened), ``predicted`` the dead-reckoning poses (n, 3);
    the correction is ``gauge_correction``'s. ``frame``: ``gauge_frame(predicted)`` when the caller has it.
    """
    frame = gauge_frame(predicted) if frame is None else frame
    u, k = gauge_correction(np.asarray(observed @ frame[0]), frame)
    info = normal.toarray() if sp.issparse(normal) else np.array(normal, dtype=float)  # type: ignore[union-attr]  # issparse: a sparse matrix; one fresh copy
    info += u @ (k @ u.T)
    return inverse(info)


def gauge_gradient(prior_gradient: np.ndarray, frame: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """N^T g (..., 3): the prior's gradient g (..., 3n) along the predicted gauge, whose Pi^T N^T g
    ``constrained_solution`` takes out of the update (through the constrained covariance)."""
    return cast(np.ndarray, (np.swapaxes(frame[0], -1, -2) @ prior_gradient[..., None])[..., 0])


def constrained_solution(
    solution: np.ndarray,
    predicted: np.ndarray,
    cov: np.ndarray,
    prior_gradient: np.ndarray,
    frame: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """Poses (..., n, 3) of the observability-constrained update, one Gauss-Newton step from the least-squares ``solution``.

    Huang, Mourikis & Roumeliotis (2010) use the constrained Jacobian H~ for the state update too, not only for the
    covariance. At the least-squares solution x* the prior's gradient g = P^-1 (x* - mu) (``prior_gradient``, (..., 3n))
    equals the observations' H^T r; its part along the predicted gauge, N^T H^T r, is the spurious information
    (H~ is blind to N). Replacing H^T r by H~^T r = H^T r - Pi^T N^T g and linearizing about x* gives
    x = x* - C Pi^T N^T g (``gauge_gradient``), with C = ``cov`` the constrained covariance (..., 3n, 3n, before ``transport``). Without it the
    swarm's estimated global rotation took a noise-driven step at every update that no covariance accounted for.
    ``frame``: ``gauge_frame(predicted)`` when the caller has it.
    """
    frame = gauge_frame(predicted) if frame is None else frame
    step = (cov @ (np.swapaxes(frame[1], -1, -2) @ gauge_gradient(prior_gradient, frame)[..., None]))[..., 0]
    return cast(np.ndarray, solution - step.reshape(solution.shape))


def inverse(info: sp.spmatrix | np.ndarray) -> np.ndarray:
    """The covariance (k, k) of an information matrix; NaN where it is singular.

    From order ``BLAS_SMALL`` on, when positive definite (the usual case): Cholesky and its inverse
    (LAPACK potrf + potri, half the flops of ``np.linalg.inv``'s LU) on one BLAS thread (SciPy's
    LAPACK spins its threads: 300 unknowns took 86 ms on a busy 2-core machine, 6.3 ms on one);
    otherwise, and below that order, the general inverse.
    """
    a = dense(info)
    if len(a) >= BLAS_SMALL:
        with blas_threads(len(a)):
            factor, bad = dpotrf(a, lower=False, clean=False)
            if bad == 0:
                upper, bad = dpotri(factor, lower=False)
        if bad == 0:  # potri fills the upper triangle: mirror it in one pass
            return cast(np.ndarray, np.where(_upper_mask(len(a)), upper, upper.T))
    try:
        return np.linalg.inv(a)
    except np.linalg.LinAlgError:
        return np.full(info.shape, np.nan)


@functools.lru_cache(maxsize=8)
def _upper_mask(k: int) -> np.ndarray:
    """(k, k) True on and above the diagonal (kept: a swarm's size rarely changes)."""
    return np.triu(np.ones((k, k), bool))


def merge_subset(prior: np.ndarray | None, updated: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """Joint covariance (3n, 3n) after an update of the robots ``keep`` (n,) alone, the others unchanged.

    ``prior`` (3n, 3n) is the covariance before the update, ``updated`` (3a, 3a) the kept robots'
    covariance after it (``constrained_covariance`` of their solve, before ``transport``). The
    observations touched only the kept robots A, so their update was linear in their prior error,
    e_A' = (I - K H) e_A + K v with (I - K H) = P_AA' P_AA^-1, and the others B keep theirs:
    P_A'B = P_AA' P_AA^-1 P_AB, P_BB unchanged. Positive semi-definite whenever P_AA' <= P_AA. A singular
    P_AA (a pose known exactly) takes the pseudo-inverse: no error there to carry over.
    """
    if keep.all():
        return updated
    assert prior is not None, "the prior is needed unless every robot is kept"
    idx = np.arange(len(prior)).reshape(-1, 3)
    a, b = idx[keep].ravel(), idx[~keep].ravel()
    p_aa = prior[np.ix_(a, a)]
    try:
        gain = np.linalg.solve(p_aa, updated).T  # P_AA' P_AA^-1 (both symmetric)
    except np.linalg.LinAlgError:  # a pose known exactly (zero prior variance, e.g. the planner's known start): the limit
        gain = (np.linalg.pinv(p_aa, hermitian=True) @ updated).T
    out = prior.copy()
    out[np.ix_(a, a)] = updated
    out[np.ix_(a, b)] = gain @ prior[np.ix_(a, b)]
    out[np.ix_(b, a)] = out[np.ix_(a, b)].T
    return out


def transport_offset(predicted: np.ndarray, solution: np.ndarray, frame: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """D = N(solution) - N(predicted) (..., 3n, 3), both rotations about the predicted centroid: ``transport``'s
    T = I + D Pi."""
    return cast(np.ndarray, gauge_basis(solution, predicted[..., :2].mean(axis=-2)) - frame[0])


def transport(
    cov: np.ndarray, predicted: np.ndarray, solution: np.ndarray, frame: tuple[np.ndarray, np.ndarray] | None = None
) -> np.ndarray:
    """T cov T^T with T = I + (N(solution) - N(predicted)) (N^T N)^-1 N^T (a rank-3 update, O(n^2)), one swarm
    ((3n, 3n), poses (n, 3)) or a batch (leading axes).

    Both rotations are about the same point (the predicted centroid): the symmetry that moves
    ``predicted`` rotates ``solution`` about that point too, and so does the next propagation.
    ``frame``: ``gauge_frame(predicted)`` when the caller has it.
    """
    frame = gauge_frame(predicted) if frame is None else frame
    d = transport_offset(predicted, solution, frame)  # (..., 3n, 3)
    d_t = np.swapaxes(d, -1, -2)
    pc = frame[1] @ cov  # (..., 3, 3n)
    # T cov T^T = cov + D Pi cov + (D Pi cov)^T + D (Pi cov Pi^T) D^T = cov + [D, (Pi cov)^T] [Pi cov + (Pi cov Pi^T) D^T; D^T]
    left = np.concatenate([d, np.swapaxes(pc, -1, -2)], axis=-1)
    out = cov + left @ np.concatenate([pc + (pc @ np.swapaxes(frame[1], -1, -2)) @ d_t, d_t], axis=-2)
    return cast(np.ndarray, 0.5 * (out + np.swapaxes(out, -1, -2)))


def transported_blocks(blocks: np.ndarray, offset: np.ndarray, pc: np.ndarray, pcp: np.ndarray) -> np.ndarray:
    """The 3x3 diagonal blocks (..., n, 3, 3) of ``transport``'s T cov T^T from cov's own (``blocks``), D
    (``offset``, ``transport_offset``), Pi cov (``pc`` (..., 3, 3n)) and Pi cov Pi^T (``pcp`` (..., 3, 3)): the same
    C + D Pi C + (D Pi C)^T + D (Pi C Pi^T) D^T, robot by robot, without the whole matrix (the planner's batch)."""
    shape = blocks.shape
    d = offset.reshape(shape[:-3] + (shape[-3], 3, 3))  # D_a (3, 3) of each robot
    pc_a = np.swapaxes(pc.reshape(shape[:-3] + (3, shape[-3], 3)), -3, -2)  # (Pi C)_{:, a} (3, 3) of each robot
    half = d @ (pc_a + 0.5 * (pcp[..., None, :, :] @ np.swapaxes(d, -1, -2)))  # D Pi C + D (Pi C Pi^T) D^T / 2
    return blocks + half + np.swapaxes(half, -1, -2)


__all__ = [
    "constrained_covariance",
    "constrained_solution",
    "gauge_basis",
    "gauge_correction",
    "gauge_frame",
    "gauge_gradient",
    "inverse",
    "merge_subset",
    "transport",
    "transport_offset",
    "transported_blocks",
]
