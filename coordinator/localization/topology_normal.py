"""Eq. B3's normal equations for a large swarm, assembled without a Jacobian matrix, and their solve reusing one
factorization (``estimate_topology`` from ``topology.LARGE_MIN`` robots).

An observation i -> j has two residuals, r = R(theta_i) z_ij + x_i - x_j, over five unknowns
(x_i, y_i, theta_i, x_j, y_j); with d r / d theta_i = g = (-(R z)_y, (R z)_x) its rows of the Jacobian are
(1, 0, g_x, -1, 0) and (0, 1, g_y, 0, -1), so its share of J^T J is eleven entries of the lower triangle
(``_ENTRIES``, five of them depending on theta_i), summed into a pattern ranked once a step with ``np.bincount``
(as ``joint_normal``): no sparse Jacobian, no sparse product, no triangle extraction at every iteration (about a
third of a 10,000-robot step's localization). The lower triangle in CSR order is the upper in CSC order, CHOLMOD's
input, so ``evaluate`` returns it and ``solve`` takes it.

The step's first system (Gauss-Newton) is factorized (CHOLMOD or QDLDL, ``sparse_lm.SparseFactor``); the later
ones, which differ from it by the headings the first step turned and the second-order term, are solved by
conjugate gradients preconditioned with that factor (``PCG_RTOL``; 7-9 iterations at 10,000 robots, each a pair
of triangular solves of ~0.05 s against ~1 s for a factorization of their 30,000 unknowns), and factorized afresh
when they have not converged within ``PCG_MAX_ITER``.

The steps are those of the sparse Jacobian's path to rounding (the sums are taken in another order) and to the
conjugate gradients' tolerance, so the minimum is the same to the solver's tolerance, not to the bit: smaller
swarms, whose results the tests pin, keep the Jacobian's path.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from coordinator.localization.sparse_lm import NormalEquations, SparseFactor, huber_weights
from coordinator.localization.topology_terms import heading_curvature, observation_jacobian, observation_residuals

# The lower triangle's entries of one observation's 5 x 5 block over (x_i, y_i, theta_i, x_j, y_j), (row, column) of
# the block, row >= column: first those that depend on theta_i (their values are in ``TopologyNormal.evaluate``), then
# those that are the residuals' weights alone (1, or Huber's IRLS weights) with the sign of ``_FIXED_SIGN``.
_ENTRIES = np.array([(2, 2), (2, 0), (2, 1), (3, 2), (4, 2), (0, 0), (1, 1), (3, 3), (4, 4), (3, 0), (4, 1)])
_VARYING = 5  # entries that depend on theta_i
_FIXED_SIGN = np.array([1.0, 1.0, 1.0, 1.0, -1.0, -1.0])[:, None]  # the others: +-w_x, +-w_y
_FIXED_AXIS = np.array([0, 1, 0, 1, 0, 1])  # ... of the x or the y residual
PCG_RTOL = 1e-6  # a preconditioned conjugate-gradient solve stops when its update is below this of its solution
FACTORED_SOLVES = 1  # systems factorized before the last factor preconditions the others
PCG_MAX_ITER = 25  # iterations after which it gives up and the system is factorized afresh


class TopologyNormal:
    """Eq. B3 of one step over the unknowns of ``cols`` ((n, 3) unknown columns per robot, -1 = fixed, as
    ``sparse_lm.PoseLayout``): ``evaluate`` and ``solve`` are ``sparse_lm.minimize``'s callbacks.

    ``start`` (n, 3) holds the fixed components; ``observer``/``observed`` index the robots, ``z`` (m, 2) the
    offsets of Eq. B1; ``huber`` as ``sparse_lm.levenberg_marquardt``'s (on each residual, IRLS).
    """

    def __init__(self, cols: np.ndarray, size: int, start: np.ndarray, observer: np.ndarray, observed: np.ndarray,
                 z: np.ndarray, huber: float | None) -> None:
        self.cols, self.size, self.start = cols, size, start
        self.observer, self.observed, self.huber = observer, observed, huber
        self.zx, self.zy = z[:, 0], z[:, 1]
        self.cols5 = np.concatenate([cols[observer, :3], cols[observed, :2]], axis=1)  # (m, 5)
        self._pattern()
        self._factor = SparseFactor()
        self._solves = 0  # systems solved so far

    def _pattern(self) -> None:
        """The lower triangle's CSR pattern (the upper's in CSC order, CHOLMOD's input) and the bin of each observation's
        entries in it (in ``_ENTRIES`` order; entries of fixed unknowns go to a last bin, dropped)."""
        size, cols5, cols = self.size, self.cols5, self.cols
        # Bins by rank among the distinct keys (row * size + column), one sort: of the diagonal (every unknown), the
        # observers' own (theta_i, x_i) and (theta_i, y_i) (one of each per robot), and the pairs' entries.
        own = (cols[:, 2] >= 0) & (cols[:, 0] >= 0)
        own_keys = (cols[own, 2] * size + cols[own, :2].T).ravel()  # theta follows x and y in the layout
        pair = _ENTRIES[:, 0] > _ENTRIES[:, 1]
        pair[[1, 2]] = False  # (theta_i, x_i), (theta_i, y_i): the own
        row, col = cols5[:, _ENTRIES[pair, 0]].T, cols5[:, _ENTRIES[pair, 1]].T
        valid = (row >= 0) & (col >= 0)
        pair_keys = np.maximum(row, col)[valid] * size + np.minimum(row, col)[valid]
        every = np.concatenate([np.arange(size, dtype=np.int64) * (size + 1), own_keys, pair_keys])
        order = np.argsort(every)
        ranked = every[order]
        new = np.concatenate([[True], ranked[1:] != ranked[:-1]])
        rank = np.empty(len(every), np.int64)
        rank[order] = np.cumsum(new) - 1
        lower = ranked[new]
        n_lower = len(lower)
        diag_bin = np.append(rank[:size], n_lower)  # by column; column -1: the last bin
        own_bin = np.full((len(cols), 2), n_lower)
        own_bin[own] = rank[size:size + len(own_keys)].reshape(2, -1).T
        pos = np.empty((len(_ENTRIES), len(cols5)), np.int64)
        on_diag = _ENTRIES[:, 0] == _ENTRIES[:, 1]
        pos[on_diag] = diag_bin[cols5[:, _ENTRIES[on_diag, 0]].T]
        pos[[1, 2]] = own_bin[self.observer].T
        pair_pos = np.full(row.shape, n_lower)
        pair_pos[valid] = rank[size + len(own_keys):]
        pos[pair] = pair_pos
        self._pos_varying, self._pos_fixed = pos[:_VARYING], pos[_VARYING:]
        rows = lower // size
        self._indptr = np.concatenate([[0], np.cumsum(np.bincount(rows, minlength=size))]).astype(np.int32)
        self._indices = (lower % size).astype(np.int32)
        self._n_lower, self._diag = n_lower, self._indptr[1:] - 1  # each row's diagonal entry is its last lower one
        self._upper = sp.csc_matrix((np.zeros(n_lower), self._indices, self._indptr), shape=(size, size))
        self._grad_pos = np.where(cols5 >= 0, cols5, size).T  # J^T r's bins (5, m), the last one dropped
        if self.huber is None:  # the weights are 1: the entries of ``_FIXED`` are constant
            ones = np.broadcast_to(_FIXED_SIGN, self._pos_fixed.shape)
            self._fixed = np.bincount(self._pos_fixed.ravel(), weights=ones.ravel(), minlength=n_lower + 1)

    def evaluate(self, x: np.ndarray) -> NormalEquations:
        """Cost, J^T J's lower triangle (CSR: ``solve`` takes it so), J^T r and the heading curvature at ``x``; ``extra``
        is None."""
        poses = self.start.copy()
        free = self.cols >= 0
        poses[free] = x[self.cols[free]]
        heading = poses[self.observer, 2]
        pi, pj = poses[self.observer], poses[self.observed]
        m = len(heading)
        rz, r = np.empty((2, m)), np.empty((2, m))
        observation_residuals(np.cos(heading), np.sin(heading), self.zx, self.zy, pi[:, 0], pi[:, 1], pj[:, 0], pj[:, 1],
                              out=(rz[0], rz[1], r[0], r[1]))
        g = np.stack(observation_jacobian(rz[0], rz[1]))  # d r / d theta_i (2, m)
        w, cost = huber_weights(r, self.huber)  # elementwise: the order of the residuals does not matter
        wg, wr = (g, r) if w is None else (w * g, w * r)
        varying = np.empty((_VARYING, m))  # in ``_ENTRIES`` order
        np.multiply(wg[0], g[0], out=varying[0])
        varying[0] += wg[1] * g[1]
        varying[1:3] = wg
        np.negative(wg, out=varying[3:5])
        lower = np.bincount(self._pos_varying.ravel(), weights=varying.ravel(), minlength=self._n_lower + 1)
        if w is None:
            lower += self._fixed
        else:
            lower += np.bincount(self._pos_fixed.ravel(), weights=(_FIXED_SIGN * w[_FIXED_AXIS]).ravel(), minlength=self._n_lower + 1)
        normal = sp.csr_matrix((lower[:-1], self._indices, self._indptr), shape=(self.size, self.size))
        grad = np.empty((5, m))  # J^T W r's share, rows (x_i, y_i, theta_i, x_j, y_j)
        grad[:2] = wr
        np.multiply(wg[0], r[0], out=grad[2])
        grad[2] += wg[1] * r[1]
        np.negative(wr, out=grad[3:])
        gradient = np.bincount(self._grad_pos.ravel(), weights=grad.ravel(), minlength=self.size + 1)[:-1]
        rw = r if w is None else r * np.sqrt(w)  # the weighted residuals, whose curvature the Jacobian's path takes
        curvature = np.bincount(self._grad_pos[2], weights=heading_curvature(rz[0], rz[1], rw[0], rw[1]), minlength=self.size + 1)[:-1]
        return NormalEquations(cost, normal, gradient, curvature)

    def solve(self, lower: sp.csr_matrix, shift: np.ndarray, rhs: np.ndarray) -> np.ndarray:
        """(A + diag(shift))^-1 rhs, A symmetric given by its ``lower`` triangle (``evaluate``'s, perhaps plus a
        diagonal): the step's first system factorized, the later ones by conjugate gradients preconditioned with that
        factor (refactorized when they do not converge within ``PCG_MAX_ITER``)."""
        upper = self._upper
        if lower.nnz != len(upper.data):  # an entry summed to exactly zero was dropped: the general path
            full = lower + sp.tril(lower, -1).T + sp.diags(shift)
            return SparseFactor(self._factor.backend).solve(full, rhs)
        np.copyto(upper.data, lower.data)  # the lower triangle in CSR order is the upper in CSC order
        upper.data[self._diag] += shift
        self._solves += 1
        if self._solves > FACTORED_SOLVES:
            x = self._pcg(upper, rhs)
            if x is not None:
                return x
        return self._factor.solve_upper(upper, rhs, same_pattern=self._solves > 1)

    def _pcg(self, upper: sp.csc_matrix, rhs: np.ndarray) -> np.ndarray | None:
        """Conjugate gradients on A x = rhs (A symmetric, given by its ``upper`` triangle) preconditioned by the last
        factorization; None when an update has not fallen below ``PCG_RTOL`` of the solution (max norm) within
        ``PCG_MAX_ITER`` iterations, or A is found not positive definite along a search direction."""
        diagonal = upper.data[self._diag]
        x = np.zeros_like(rhs)
        res = rhs.copy()
        z = self._factor.apply(res)
        p = z.copy()
        rz = float(res @ z)
        for _ in range(PCG_MAX_ITER):
            ap = upper @ p + upper.T @ p - diagonal * p
            curvature = float(p @ ap)
            if not curvature > 0.0:  # not positive definite (or not finite): the factorization decides
                return None
            alpha = rz / curvature
            x += alpha * p
            if abs(alpha) * np.abs(p).max() <= PCG_RTOL * np.abs(x).max():
                return x
            res -= alpha * ap
            z = self._factor.apply(res)
            rz, rz_old = float(res @ z), rz
            p = z + (rz / rz_old) * p
        return None


__all__ = ["PCG_MAX_ITER", "PCG_RTOL", "TopologyNormal"]
