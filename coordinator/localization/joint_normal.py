"""Normal equations of the joint problem (Section 5.3), assembled without a Jacobian matrix.

The joint localizer minimises the whitened dead-reckoning prior residuals W (p - mu) plus the
whitened range and bearing residuals of every observation. An observation i -> j depends on
five unknowns, (x_i, y_i, theta_i, x_j, y_j) (``range_bearing.observation_blocks``), so its share
of J^T J is a 5 x 5 block and of J^T r a 5-vector. They are summed straight into the normal
matrix with ``np.bincount`` at positions computed once per problem: the pattern does not change
between Levenberg-Marquardt iterations, so the sparse factorization (``sparse_lm.SparseLDL``) only
refactorizes numerically (``JointProblem.solve``), and no sparse Jacobian is built (its construction dominated a step).

Dense up to ``sparse_lm.DENSE_LIMIT`` unknowns or with a dense prior (the carried joint
covariance makes the information dense); CSR with a fixed pattern otherwise. Same residuals,
weights and Huber IRLS (on every whitened residual) as ``range_bearing`` with
``sparse_lm.levenberg_marquardt``, so both give the same steps. Units: metres and radians.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.linalg import cho_factor, cho_solve

from coordinator.localization.range_bearing import bearing_weights, observation_blocks
from coordinator.localization.sparse_lm import DENSE_LIMIT, NormalEquations, SparseLDL, huber_weights
from runtime.config import ModelConfig
from runtime.geometry import wrap_angle


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
            return
        keys = np.sort(np.concatenate([obs_keys, prior_keys, np.arange(size) * (size + 1)]))
        keys = keys[np.concatenate([[True], keys[1:] != keys[:-1]])]  # unique (np.unique hashes: 5x slower here)
        self._obs_pos = np.searchsorted(keys, obs_keys)
        self._prior_pos = np.searchsorted(keys, prior_keys)
        self._nnz = len(keys)
        rows, cols = keys // size, keys % size
        self._indices = cols.astype(np.int32)
        self._indptr = np.concatenate([[0], np.cumsum(np.bincount(rows, minlength=size))]).astype(np.int32)
        # The lower triangle in CSR order is the upper triangle in CSC order (the matrix is symmetric),
        # QDLDL's input; each row's diagonal entry is its last lower one.
        self._lower = cols <= rows
        self._lower_indices = self._indices[self._lower]
        self._lower_indptr = np.concatenate([[0], np.cumsum(np.bincount(rows[self._lower], minlength=size))]).astype(np.int32)
        self._lower_diag = self._lower_indptr[1:] - 1
        self._ldl = SparseLDL()

    def residuals(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Whitened prior residuals (3n,) and observation residuals (m, 2) at ``x``."""
        poses = x.reshape(self.n, 3)
        diff = poses - self.mean
        diff[:, 2] = wrap_angle(diff[:, 2])
        if self.joint_prior:
            prior = self.sqrt_info @ diff.ravel()
        else:
            prior = np.einsum("nab,nb->na", self.sqrt_info, diff).ravel()
        obs, _ = observation_blocks(poses, *self.obs, self.cfg, self.w_b)
        return prior, obs

    def prior_gradient(self, x: np.ndarray) -> np.ndarray:
        """The prior's share of the gradient J^T r at ``x`` (3n,): P^-1 (x - mu), Huber-weighted like ``evaluate``."""
        diff = x.reshape(self.n, 3) - self.mean
        diff[:, 2] = wrap_angle(diff[:, 2])
        if self.joint_prior:
            r_p = self.sqrt_info @ diff.ravel()
            w_p, _ = huber_weights(r_p, self.huber)
            return self.sqrt_info.T @ (r_p if w_p is None else w_p * r_p)
        r_p = np.einsum("nab,nb->na", self.sqrt_info, diff)
        w_p, _ = huber_weights(r_p, self.huber)
        return np.einsum("nba,nb->na", self.sqrt_info, r_p if w_p is None else w_p * r_p).ravel()

    def evaluate(self, x: np.ndarray) -> NormalEquations:
        """Cost, J^T J and J^T r at ``x`` (``sparse_lm.minimize``'s callback)."""
        poses = x.reshape(self.n, 3)
        diff = poses - self.mean
        diff[:, 2] = wrap_angle(diff[:, 2])
        res, jac = observation_blocks(poses, *self.obs, self.cfg, self.w_b)
        w_obs, cost_obs = huber_weights(res, self.huber)
        wj = jac if w_obs is None else jac * w_obs[:, :, None]
        blocks = wj[:, 0, :, None] * jac[:, 0, None, :] + wj[:, 1, :, None] * jac[:, 1, None, :]  # (m, 5, 5)
        g5 = wj[:, 0] * res[:, :1] + wj[:, 1] * res[:, 1:]
        if self.joint_prior:
            r_p = self.sqrt_info @ diff.ravel()
            w_p, cost_p = huber_weights(r_p, self.huber)
            info = self.prior_info if w_p is None else self.sqrt_info.T @ (w_p[:, None] * self.sqrt_info)
            g_prior = self.sqrt_info.T @ (r_p if w_p is None else w_p * r_p)
            prior_vals = None
        else:
            r_p = np.einsum("nab,nb->na", self.sqrt_info, diff)
            w_p, cost_p = huber_weights(r_p, self.huber)
            info = self.prior_info if w_p is None else np.swapaxes(self.sqrt_info, -1, -2) @ (w_p[:, :, None] * self.sqrt_info)
            g_prior = np.einsum("nba,nb->na", self.sqrt_info, r_p if w_p is None else w_p * r_p).ravel()
            prior_vals = info.ravel()
        data = np.bincount(self._obs_pos, weights=blocks.ravel(), minlength=self._nnz)
        if prior_vals is not None:
            data += np.bincount(self._prior_pos, weights=prior_vals, minlength=self._nnz)
        if self.dense:
            normal = data.reshape(self.size, self.size)
            if self.joint_prior:
                normal += info
        else:
            normal = sp.csr_matrix((data, self._indices, self._indptr), shape=(self.size, self.size))
        gradient = np.bincount(self.cols5.ravel(), weights=g5.ravel(), minlength=self.size) + g_prior
        return NormalEquations(cost_obs + cost_p, normal, gradient, None, blocks)

    def solve(self, normal: sp.spmatrix | np.ndarray, shift: np.ndarray, rhs: np.ndarray) -> np.ndarray:
        """(normal + diag(shift))^-1 rhs (``sparse_lm.minimize``'s step): dense Cholesky, or QDLDL on the fixed
        pattern, refactorized numerically after the first call."""
        if self.dense:
            a = normal.copy()
            a.flat[:: self.size + 1] += shift
            if self.size <= DENSE_LIMIT:  # small: LAPACK's call overhead dominates, not its flops
                return np.linalg.solve(a, rhs)
            try:
                return cho_solve(cho_factor(a, check_finite=False), rhs, check_finite=False)
            except np.linalg.LinAlgError:
                return np.linalg.solve(a, rhs)
        data = normal.data[self._lower]
        data[self._lower_diag] += shift
        upper = sp.csc_matrix((data, self._lower_indices, self._lower_indptr), shape=(self.size, self.size))
        return self._ldl.solve_upper(upper, rhs, same_pattern=True)

    def observation_normal(self, blocks: np.ndarray) -> sp.spmatrix | np.ndarray:
        """H^T H (3n, 3n) of the observations alone, from ``evaluate``'s ``extra`` blocks."""
        data = np.bincount(self._obs_pos, weights=blocks.ravel(), minlength=self._nnz)
        if self.dense:
            return data.reshape(self.size, self.size)
        return sp.csr_matrix((data, self._indices, self._indptr), shape=(self.size, self.size))


__all__ = ["JointProblem"]
