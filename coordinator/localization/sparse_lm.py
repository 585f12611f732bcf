"""Sparse Levenberg-Marquardt over pose unknowns, shared by every localizer.

Residuals and Jacobians are assembled vectorised (COO triplets); the normal equations
(J^T J + mu diag(J^T J)) dx = -J^T r are solved densely for small problems and with
SciPy's sparse LU otherwise, so a 1000-robot swarm with range-limited sensing stays fast.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import spsolve

DENSE_LIMIT = 400  # unknowns up to which a dense solve is faster than sparse LU


class PoseLayout:
    """Maps robot pose components to columns of the unknown vector (-1 = held fixed)."""

    def __init__(self, free_position: np.ndarray, free_heading: np.ndarray) -> None:
        n = len(free_position)
        counts = np.stack([free_position, free_position, free_heading], axis=1).astype(np.int64)
        cols = np.cumsum(counts.ravel()).reshape(n, 3) - 1
        self.cols = np.where(counts > 0, cols, -1)
        self.size = int(counts.sum())

    def pack(self, poses: np.ndarray) -> np.ndarray:
        """Unknown vector holding the free components of ``poses`` (n, 3)."""
        vec = np.empty(self.size)
        mask = self.cols >= 0
        vec[self.cols[mask]] = poses[mask]
        return vec

    def unpack(self, vec: np.ndarray, fixed: np.ndarray) -> np.ndarray:
        """Poses (n, 3): free components from ``vec``, the rest from ``fixed``."""
        poses = np.array(fixed, dtype=float, copy=True)
        mask = self.cols >= 0
        poses[mask] = vec[self.cols[mask]]
        return poses


def jacobian(n_rows: int, n_cols: int, rows: np.ndarray, cols: np.ndarray, vals: np.ndarray) -> sp.csr_matrix:
    """CSR Jacobian from COO triplets; entries with column -1 (fixed unknowns) are dropped."""
    keep = cols >= 0
    return sp.csr_matrix((vals[keep], (rows[keep], cols[keep])), shape=(n_rows, n_cols))


def solve_normal(a: sp.spmatrix, b: np.ndarray) -> np.ndarray:
    """Solve the symmetric positive (semi)definite system a x = b."""
    if a.shape[0] <= DENSE_LIMIT:
        return np.linalg.solve(a.toarray(), b)
    return spsolve(a.tocsc(), b)


@dataclass(frozen=True)
class LsqResult:
    x: np.ndarray
    cost: float
    iterations: int
    converged: bool
    normal_matrix: sp.csr_matrix  # J^T J at the solution (Gauss-Newton information)


def levenberg_marquardt(
    residuals: Callable[[np.ndarray], tuple[np.ndarray, sp.csr_matrix]],
    x0: np.ndarray,
    *,
    second_order: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
    huber: float | None = None,
    max_iter: int = 100,
    xtol: float = 1e-10,
    ftol: float = 1e-12,
) -> LsqResult:
    """Minimise sum(rho(r_k(x))) with rho quadratic (or Huber beyond ``huber``, via IRLS).

    ``residuals(x)`` returns the residual vector and its sparse Jacobian; residuals
    should be whitened (unit variance) when ``huber`` is used, so the threshold is in sigmas.
    ``second_order(x, r)``, if given, returns the diagonal of sum_k r_k d^2 r_k / dx^2,
    the term Gauss-Newton drops; adding it (kept >= 10 % of the Gauss-Newton diagonal)
    restores fast convergence where soft modes meet curved residuals (rotations).
    """

    def weighted(x: np.ndarray) -> tuple[np.ndarray, sp.csr_matrix, float]:
        r, jac = residuals(x)
        if huber is None:
            return r, jac, 0.5 * float(r @ r)
        a = np.abs(r)
        w = np.where(a <= huber, 1.0, huber / np.maximum(a, 1e-300))
        cost = float(np.sum(np.where(a <= huber, 0.5 * r * r, huber * a - 0.5 * huber * huber)))
        sw = np.sqrt(w)
        return r * sw, sp.diags(sw) @ jac, cost

    x = np.asarray(x0, dtype=float).copy()
    r, jac, cost = weighted(x)
    mu = 1e-8
    converged = False
    it = 0
    for it in range(1, max_iter + 1):
        a = (jac.T @ jac).tocsr()
        g = jac.T @ r
        diag = np.maximum(a.diagonal(), 1e-12)
        if second_order is not None:
            a = a + sp.diags(np.maximum(second_order(x, r), -0.9 * diag))
        while True:
            dx = solve_normal(a + sp.diags(mu * diag), -g)
            x_new = x + dx
            r_new, jac_new, cost_new = weighted(x_new)
            if np.isfinite(cost_new) and cost_new <= cost * (1 + 1e-12) + 1e-300:
                mu = max(mu / 10.0, 1e-12)
                break
            mu *= 10.0
            if mu > 1e10:
                return LsqResult(x, cost, it, converged, a)
        small_step = np.max(np.abs(dx), initial=0.0) <= xtol * (1.0 + np.max(np.abs(x), initial=0.0))
        small_gain = cost - cost_new <= ftol * max(cost, 1e-300)
        x, r, jac, cost = x_new, r_new, jac_new, cost_new
        if small_step or small_gain:
            converged = True
            break
    return LsqResult(x, cost, it, converged, (jac.T @ jac).tocsr())
