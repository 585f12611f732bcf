"""Normal equations of the joint problem (Section 5.3), assembled without a Jacobian matrix.

The joint localizer minimises the whitened dead-reckoning prior residuals W (p - mu) plus the
whitened range and bearing residuals of every observation. An observation i -> j depends on
five unknowns, (x_i, y_i, theta_i, x_j, y_j) (``range_bearing.observation_blocks``), so its share
of J^T J is a 5 x 5 block and of J^T r a 5-vector. They are summed straight into the normal
matrix with ``np.bincount`` at positions computed once per problem: the pattern does not change
between Levenberg-Marquardt iterations, so the sparse factorization (``sparse_lm.SparseFactor``) only
refactorizes numerically (``JointProblem.solve``), and no sparse Jacobian is built (its construction dominated a step).

Dense up to ``sparse_lm.DENSE_LIMIT`` unknowns or with a dense prior (the carried joint
covariance makes the information dense); CSR with a fixed pattern otherwise. Same residuals,
weights and Huber IRLS (on every whitened residual) as ``range_bearing`` with
``sparse_lm.levenberg_marquardt``, so both give the same steps. Units: metres and radians.
"""

from __future__ import annotations

from typing import cast

import numpy as np
import scipy.sparse as sp
from scipy.linalg.lapack import dposv

from coordinator.localization.range_bearing import bearing_weights, observation_blocks, pose_difference
from coordinator.localization.sparse_lm import DENSE_LIMIT, NormalEquations, SparseFactor, huber_weights
from runtime.models.config import ModelConfig

# Entries of the normal matrix (size^2) up to which its pattern is ranked with a dense mark-and-count map
# (1 MB of flags and a 4 MB count, up to ~340 robots): sorting and searching the ~25 m entry keys took ~3 x an evaluation at n = 100.
RANK_MAP_LIMIT = 1 << 20


class JointProblem:
    """The joint problem of one step: unknowns are all poses, x = poses.ravel() (3n,).

    ``sqrt_info`` whitens the prior: per robot (n, 3, 3) or joint (3n, 3n), W^T W = P^-1.
    ``observer``/``observed`` index the poses; ``huber`` is in sigmas (None: least squares).
    ``NormalEquations.extra`` holds the observations' 5 x 5 blocks, for ``observation_normal``.
    """

    def __init__(
        self,
        mean: np.ndarray,
        sqrt_info: np.ndarray,
        observer: np.ndarray,
        observed: np.ndarray,
        range_m: np.ndarray,
        bearing_rad: np.ndarray,
        cfg: ModelConfig,
        huber: float | None = None,
    ) -> None:
        self.mean = np.asarray(mean, dtype=float)
        self.n = n = len(self.mean)
        self.size = size = 3 * n
        self.sqrt_info = sqrt_info
        self.joint_prior = sqrt_info.ndim == 2
        self.obs = (observer, observed, range_m, bearing_rad)
        self.w_b = bearing_weights(range_m, cfg)  # fixed by the measured ranges
        self.cfg = cfg
        self.huber = huber
        self.dense = self.joint_prior or size <= DENSE_LIMIT
        if huber is None:  # the prior's information is constant: form it once
            self.prior_info = sqrt_info.T @ sqrt_info if self.joint_prior else np.swapaxes(sqrt_info, -1, -2) @ sqrt_info
        self.cols5 = np.stack([3 * observer, 3 * observer + 1, 3 * observer + 2, 3 * observed, 3 * observed + 1], axis=1)
        obs_keys = (self.cols5[:, :, None] * size + self.cols5[:, None, :]).ravel()  # (m * 25,) row-major entries
        block = 3 * np.arange(n)[:, None, None] + np.arange(3)
        prior_keys = (block * size + np.swapaxes(block, 1, 2)).ravel()  # per-robot 3x3 diagonal blocks
        if self.dense:
            self._obs_pos, self._prior_pos, self._nnz = obs_keys, prior_keys, size * size
        else:
            self._sparse_pattern(size, obs_keys, prior_keys)
        if huber is None and not self.joint_prior:  # the prior's share of the normal matrix, placed once
            self._prior_data = np.bincount(self._prior_pos, weights=self.prior_info.ravel(), minlength=self._nnz)

    def _sparse_pattern(self, size: int, obs_keys: np.ndarray, prior_keys: np.ndarray) -> None:
        """CSR pattern of the normal matrix and the positions of the observation and prior entries in it."""
        diag_keys = np.arange(size) * (size + 1)
        if size * size <= RANK_MAP_LIMIT:  # mark the used entries, rank them by a running count: no sort
            used = np.zeros(size * size, bool)
            used[obs_keys] = used[prior_keys] = used[diag_keys] = True
            keys = np.flatnonzero(used)
            rank = np.cumsum(used, dtype=np.int32)  # rank[k] - 1: position of key k among the used ones
            self._obs_pos, self._prior_pos = rank[obs_keys] - 1, rank[prior_keys] - 1
        else:
            keys = np.sort(np.concatenate([obs_keys, prior_keys, diag_keys]))
            keys = keys[np.concatenate([[True], keys[1:] != keys[:-1]])]  # unique (np.unique hashes: 5x slower here)
            self._obs_pos = np.searchsorted(keys, obs_keys)
            self._prior_pos = np.searchsorted(keys, prior_keys)
        self._nnz = len(keys)
        rows, cols = keys // size, keys % size
        self._indices = cols.astype(np.int32)
        self._indptr = np.concatenate([[0], np.cumsum(np.bincount(rows, minlength=size))]).astype(np.int32)
        # The lower triangle in CSR order is the upper triangle in CSC order (the matrix is symmetric),
        # the sparse factorization's input; each row's diagonal entry is its last lower one.
        lower = cols <= rows
        self._lower_at = np.flatnonzero(lower)
        lower_indptr = np.concatenate([[0], np.cumsum(np.bincount(rows[lower], minlength=size))]).astype(np.int32)
        self._lower_diag = lower_indptr[1:] - 1
        # One CSC matrix per problem whose values ``solve`` overwrites (no matrix construction per iteration).
        self._upper = sp.csc_matrix((np.zeros(len(self._lower_at)), self._indices[lower], lower_indptr), shape=(size, size))
        self._ldl = SparseFactor()

    def _difference(self, x: np.ndarray) -> np.ndarray:
        """p - mu (n, 3) at ``x``, heading differences wrapped."""
        return pose_difference(x.reshape(self.n, 3), self.mean)

    def _prior(self, diff: np.ndarray, information: bool = True) -> tuple[float, np.ndarray, np.ndarray | None]:
        """Cost, gradient (3n,) and Huber-weighted information of the prior terms at p - mu = ``diff``.

        The information is None where it is the constant ``prior_info`` (no Huber loss) or not asked
        for; else (3n, 3n) for a joint prior, (n, 3, 3) per robot.
        """
        w = self.sqrt_info
        if self.joint_prior:
            r_p = w @ diff.ravel()
            w_p, cost = huber_weights(r_p, self.huber)
            if w_p is None:
                return cost, w.T @ r_p, None
            return cost, w.T @ (w_p * r_p), w.T @ (w_p[:, None] * w) if information else None
        if self.huber is None:  # constant information: gradient P^-1 (p - mu), cost (p - mu) . P^-1 (p - mu) / 2
            gradient = np.matmul(self.prior_info, diff[:, :, None]).ravel()
            return 0.5 * float(diff.ravel() @ gradient), gradient, None
        r_p = np.einsum("nab,nb->na", w, diff)
        w_p, cost = huber_weights(r_p, self.huber)
        gradient = np.einsum("nba,nb->na", w, w_p * r_p).ravel()
        return cost, gradient, np.swapaxes(w, -1, -2) @ (w_p[:, :, None] * w) if information else None

    def residuals(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Whitened prior residuals (3n,) and observation residuals (m, 2) at ``x``."""
        diff = self._difference(x)
        if self.joint_prior:
            prior = self.sqrt_info @ diff.ravel()
        else:
            prior = np.einsum("nab,nb->na", self.sqrt_info, diff).ravel()
        obs, _ = observation_blocks(x.reshape(self.n, 3), *self.obs, self.cfg, self.w_b)
        return prior, obs

    def prior_gradient(self, x: np.ndarray) -> np.ndarray:
        """The prior's share of the gradient J^T r at ``x`` (3n,): P^-1 (x - mu), Huber-weighted like ``evaluate``."""
        return self._prior(self._difference(x), information=False)[1]

    def evaluate(self, x: np.ndarray) -> NormalEquations:
        """Cost, J^T J and J^T r at ``x`` (``sparse_lm.minimize``'s callback)."""
        poses = x.reshape(self.n, 3)
        res, jac = observation_blocks(poses, *self.obs, self.cfg, self.w_b)
        w_obs, cost_obs = huber_weights(res, self.huber)
        wj = jac if w_obs is None else jac * w_obs[:, :, None]
        blocks = np.multiply(wj[:, 0, :, None], jac[:, 0, None, :])  # (m, 5, 5): range, then bearing outer products
        blocks += wj[:, 1, :, None] * jac[:, 1, None, :]
        g5 = wj[:, 0] * res[:, :1] + wj[:, 1] * res[:, 1:]
        cost_p, g_prior, info = self._prior(self._difference(x))
        data = np.bincount(self._obs_pos, weights=blocks.ravel(), minlength=self._nnz)
        if not self.joint_prior:
            data += self._prior_data if info is None else np.bincount(self._prior_pos, weights=info.ravel(), minlength=self._nnz)
        if self.dense:
            normal = data.reshape(self.size, self.size)
            if self.joint_prior:
                normal += self.prior_info if info is None else info
        else:
            normal = sp.csr_matrix((data, self._indices, self._indptr), shape=(self.size, self.size))
        gradient = np.bincount(self.cols5.ravel(), weights=g5.ravel(), minlength=self.size) + g_prior
        return NormalEquations(cost_obs + cost_p, normal, gradient, None, blocks)

    def solve(self, normal: sp.spmatrix | np.ndarray, shift: np.ndarray, rhs: np.ndarray) -> np.ndarray:
        """(normal + diag(shift))^-1 rhs (``sparse_lm.minimize``'s step): dense Cholesky, or the sparse factorization on the
        fixed pattern, refactorized numerically after the first call."""
        if self.dense:  # LAPACK's Cholesky solve called directly (np.linalg.solve's wrapper: 2.5x its time at n = 10)
            a = normal.copy()
            a.flat[:: self.size + 1] += shift
            _, x, bad = dposv(a, rhs, overwrite_a=True)
            if bad == 0:
                return cast(np.ndarray, x)
            a = normal.copy()  # not positive definite: the general solver (raises if singular)
            a.flat[:: self.size + 1] += shift
            return np.linalg.solve(a, rhs)
        upper = self._upper  # the lower triangle's values (in CSR order) are the upper's in CSC order
        np.take(normal.data, self._lower_at, out=upper.data)
        upper.data[self._lower_diag] += shift
        return self._ldl.solve_upper(upper, rhs, same_pattern=True)

    def observation_normal(self, blocks: np.ndarray) -> sp.spmatrix | np.ndarray:
        """H^T H (3n, 3n) of the observations alone, from ``evaluate``'s ``extra`` blocks."""
        data = np.bincount(self._obs_pos, weights=blocks.ravel(), minlength=self._nnz)
        if self.dense:
            return data.reshape(self.size, self.size)
        return sp.csr_matrix((data, self._indices, self._indptr), shape=(self.size, self.size))


__all__ = ["JointProblem"]
