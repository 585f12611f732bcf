"""Sparse Levenberg-Marquardt over pose unknowns, shared by every localizer.

Residuals and Jacobians are assembled vectorised (COO triplets); the normal equations
(J^T J + mu diag(J^T J)) dx = -J^T r are solved densely for small problems and with a
sparse LDL^T factorization (QDLDL with an approximate-minimum-degree ordering, its symbolic analysis reused
across iterations)
otherwise, so a 1000-robot swarm with range-limited sensing stays fast.

Small problems (up to ``DENSE_JACOBIAN_LIMIT`` unknowns) never touch scipy.sparse: the Jacobian is
a dense array built by ``np.bincount`` from the triplets, whose per-call overhead is a few
microseconds instead of the ~100 us of building sparse matrices, which dominated the
10-robot step. Dense algebra on bigger problems runs with one BLAS thread (``blas_threads``):
on a busy 2-core machine multi-threaded OpenBLAS is many times slower for these sizes.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import overload

import numpy as np
import qdldl
import scipy.sparse as sp
from threadpoolctl import ThreadpoolController

DENSE_LIMIT = 64  # unknowns up to which a dense solve beats the sparse LDL^T (a 300x300 dense LU was ~3 ms)
DENSE_JACOBIAN_LIMIT = 64  # unknowns up to which a dense Jacobian (and dense J^T J) beats building sparse ones
PRED_MU_MAX = 1e-6  # damping up to which a step's predicted decrease stands for the undamped one (``minimize``'s ptol)
BLAS_SMALL = 96  # matrix order below which OpenBLAS stays single-threaded anyway (no limit needed)
_THREADPOOLS = ThreadpoolController()


def blas_threads(size: int):
    """Context limiting BLAS to one thread when dense algebra of order ``size`` follows (a no-op when small)."""
    if size < BLAS_SMALL:
        return contextlib.nullcontext()
    return _THREADPOOLS.limit(limits=1, user_api="blas")


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


def jacobian(n_rows: int, n_cols: int, rows: np.ndarray, cols: np.ndarray, vals: np.ndarray) -> sp.csr_matrix | np.ndarray:
    """Jacobian from COO triplets (duplicates summed); entries with column -1 (fixed unknowns) are dropped.

    Dense (ndarray) up to ``DENSE_JACOBIAN_LIMIT`` columns, CSR above.
    """
    keep = cols >= 0
    if n_cols <= DENSE_JACOBIAN_LIMIT:
        flat = rows[keep] * n_cols + cols[keep]
        return np.bincount(flat, weights=vals[keep], minlength=n_rows * n_cols).reshape(n_rows, n_cols)
    return sp.csr_matrix((vals[keep], (rows[keep], cols[keep])), shape=(n_rows, n_cols))


def dense(a: sp.spmatrix | np.ndarray) -> np.ndarray:
    """``a`` as a dense array."""
    return a if isinstance(a, np.ndarray) else a.toarray()


def solve_normal(a: sp.spmatrix | np.ndarray, b: np.ndarray, factor: SparseLDL | None = None) -> np.ndarray:
    """Solve the symmetric positive definite system a x = b: dense up to ``DENSE_LIMIT`` unknowns, else by a
    sparse LDL^T (``SparseLDL``; pass one to reuse its symbolic analysis across calls with the same pattern)."""
    if isinstance(a, np.ndarray) or a.shape[0] <= DENSE_LIMIT:
        return np.linalg.solve(dense(a), b)
    return (factor or SparseLDL()).solve(a, b)


class SparseLDL:
    """Sparse LDL^T factorization (QDLDL, approximate-minimum-degree ordering) of symmetric positive definite
    matrices, keeping its ordering and symbolic analysis while the sparsity pattern stays the same.

    Levenberg-Marquardt factorizes J^T J + mu D with one pattern at every iteration: the numeric
    refactorization alone is 2.5-3x faster than a fresh factorization, itself 2-4x faster than SciPy's
    SuperLU (300 unknowns: 0.34 / 0.95 / 4.1 ms; 3000: 16 / 43 / 77 ms).
    """

    def __init__(self) -> None:
        self._solver: qdldl.Solver | None = None
        self._pattern: tuple[np.ndarray, np.ndarray] | None = None

    def solve(self, a: sp.spmatrix, b: np.ndarray) -> np.ndarray:
        """a^-1 b, refactorizing numerically when ``a`` keeps the last pattern (compared here)."""
        upper = sp.triu(a, format="csc")
        upper.sort_indices()
        pattern = (upper.indptr, upper.indices)
        same = self._pattern is not None and all(np.array_equal(x, y) for x, y in zip(pattern, self._pattern, strict=True))
        self._pattern = pattern
        return self.solve_upper(upper, b, same)

    def solve_upper(self, upper: sp.csc_matrix, b: np.ndarray, same_pattern: bool) -> np.ndarray:
        """a^-1 b from a's upper triangle (CSC, sorted); ``same_pattern``: the caller knows it is the last one's."""
        if same_pattern and self._solver is not None:
            self._solver.update(upper, upper=True)
        else:
            self._solver = qdldl.Solver(upper, upper=True)
        return self._solver.solve(b)


@overload
def huber_weights(r: np.ndarray, huber: float) -> tuple[np.ndarray, float]: ...


@overload
def huber_weights(r: np.ndarray, huber: None) -> tuple[None, float]: ...


@overload
def huber_weights(r: np.ndarray, huber: float | None) -> tuple[np.ndarray | None, float]: ...


def huber_weights(r: np.ndarray, huber: float | None) -> tuple[np.ndarray | None, float]:
    """IRLS weights of whitened residuals ``r`` (None: all 1, plain least squares) and their cost
    sum(rho(r)), rho quadratic within ``huber`` sigmas and linear beyond."""
    if huber is None:
        flat = r.ravel()
        return None, 0.5 * float(flat @ flat)
    a = np.abs(r)
    cost = float(np.sum(np.where(a <= huber, 0.5 * r * r, huber * a - 0.5 * huber * huber)))
    return np.where(a <= huber, 1.0, huber / np.maximum(a, 1e-300)), cost


@dataclass(frozen=True)
class NormalEquations:
    """The Gauss-Newton system of a least-squares problem at one point.

    ``normal`` = J^T J (whitened, Huber-weighted), ``gradient`` = J^T r, ``curvature`` the diagonal
    second-order term to add for the step (or None), ``extra`` whatever the problem wants back at
    the solution (the Jacobian, for residual problems).
    """

    cost: float
    normal: sp.spmatrix | np.ndarray
    gradient: np.ndarray
    curvature: np.ndarray | None = None
    extra: object = None


@dataclass(frozen=True)
class LsqResult:
    x: np.ndarray
    cost: float
    iterations: int
    converged: bool
    normal_matrix: sp.spmatrix | np.ndarray  # J^T J at the solution (Gauss-Newton information; dense when small)
    extra: object  # the problem's ``NormalEquations.extra`` there (the Jacobian, for residual problems)


def add_diagonal(a: sp.spmatrix | np.ndarray, values: np.ndarray) -> sp.spmatrix | np.ndarray:
    """a + diag(values), dense or sparse like ``a``."""
    if isinstance(a, np.ndarray):
        out = a.copy()
        out.flat[:: len(out) + 1] += values
        return out
    return a + sp.diags(values)


# The Levenberg-Marquardt rule, defined once for ``minimize`` (one problem) and ``batch``'s lock-step driver (many
# problems at once): the damping and its scale, the clamp of the second-order term, acceptance and convergence.
# The functions take floats or arrays (one value per problem).
MU_START = 1e-8  # damping of the first step
MU_MIN = 1e-12  # the damping never falls below this on accepted steps
MU_MAX = 1e10  # a problem whose damping grows beyond this gives up (not converged)
MU_FACTOR = 10.0  # damping divided by this after an accepted step, multiplied after a rejected one
ACCEPT_SLACK = 1e-12  # relative cost increase a step may bring and still be accepted (rounding at a minimum)
DIAG_FLOOR = 1e-12  # floor of diag(J^T J) as the damping scale D (an unknown nothing constrains yet)
CURVATURE_FLOOR = 0.9  # the second-order term C is kept >= -0.9 D
MAX_ITER = 100  # accepted steps at most
_TINY = 1e-300  # keeps the relative tests meaningful at a zero cost


def damping_scale(diagonal: np.ndarray) -> np.ndarray:
    """D: diag(J^T J) floored at ``DIAG_FLOOR`` (the damping adds mu D)."""
    return np.maximum(diagonal, DIAG_FLOOR)


def clamp_curvature(curvature: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """The second-order term C kept >= -``CURVATURE_FLOOR`` D, so A + C + mu D stays positive definite."""
    return np.maximum(curvature, -CURVATURE_FLOOR * scale)


class ScalarOps:
    """The numpy functions the rule uses, for one problem's Python floats (numpy's cost ~1 us per call on
    scalars, which added ~10 % to a 10-robot step): pass ``xp=ScalarOps`` to evaluate the same expressions."""

    maximum = staticmethod(max)
    isfinite = staticmethod(math.isfinite)

    @staticmethod
    def where(condition: bool, a: float, b: float) -> float:
        return a if condition else b

    @staticmethod
    def logical_and(a: bool, b: bool) -> bool:
        return a and b

    @staticmethod
    def logical_or(a: bool, b: bool) -> bool:
        return a or b

    @staticmethod
    def logical_not(a: bool) -> bool:
        return not a


def step_outcome(cost, cost_new, step_max, x_max, mu, xtol: float, ftol: float, xp=np) -> tuple:
    """What a trial step does: (accepted, converged, next damping, given up), per problem.

    Arguments are arrays (one value per problem; ``xp`` numpy) or floats (``xp`` = ``ScalarOps``).
    ``step_max`` is the step's largest |component|, ``x_max`` that of the point it started from. A step is
    accepted when finite and not raising the cost beyond rounding (``ACCEPT_SLACK``); the damping is then
    divided by ``MU_FACTOR`` (floor ``MU_MIN``), else multiplied. Converged: an accepted step below
    ``xtol`` (1 + max |x|) or lowering the cost by less than ``ftol`` of it (the new point is the solution),
    or a rejected step below ``xtol`` (1 + max |x|): the problem sits at its minimum, where rounding decides
    the cost (the old point is the solution). Given up: a rejected step that took the damping beyond ``MU_MAX``.
    """
    accept = xp.logical_and(xp.isfinite(cost_new), cost_new <= cost * (1 + ACCEPT_SLACK) + _TINY)
    gain_small = cost - cost_new <= ftol * xp.maximum(cost, _TINY)
    converged = xp.logical_or(step_max <= xtol * (1.0 + x_max), xp.logical_and(accept, gain_small))
    mu_next = xp.where(accept, xp.maximum(mu / MU_FACTOR, MU_MIN), mu * MU_FACTOR)
    gave_up = xp.logical_and(xp.logical_not(xp.logical_or(accept, converged)), mu_next > MU_MAX)
    return accept, converged, mu_next, gave_up


def settled(predicted, cost, mu, ptol: float, xp=np):
    """Converged before the step (``minimize``'s ``ptol``): its predicted decrease -g.dx / 2 below ``ptol`` of the
    cost while the damping is negligible (mu <= ``PRED_MU_MAX``; a damped step under-predicts)."""
    return xp.logical_and(mu <= PRED_MU_MAX, predicted <= ptol * cost)


def minimize(
    evaluate: Callable[[np.ndarray], NormalEquations],
    x0: np.ndarray,
    *,
    solve: Callable[[sp.spmatrix | np.ndarray, np.ndarray, np.ndarray], np.ndarray] | None = None,
    max_iter: int = MAX_ITER,
    xtol: float = 1e-10,
    ftol: float = 1e-12,
    ptol: float | None = None,
) -> LsqResult:
    """Levenberg-Marquardt on the normal equations ``evaluate(x)`` returns.

    ``solve(a, shift, rhs)`` solves (a + diag(shift)) dx = rhs (default: ``solve_normal``, its
    factorization reused while the pattern stays).

    Step (A + C + mu D) dx = -g with D = diag(A) (``damping_scale``) and C the curvature
    (``clamp_curvature``) from the second iteration on: the first is a Gauss-Newton step (C = 0), since the
    second-order term is only trustworthy near a solution (from a dead-reckoning start with 3 cm
    residuals, A + C of 500 robots' topology was nearly singular: a 7.5 m step, rejected four
    times before mu had grown enough; the Gauss-Newton step moved 2 cm). mu starts at ``MU_START``; each trial
    step's acceptance, convergence (a step below ``xtol`` relative to x, or a cost decrease below ``ftol``
    relative to the cost), next damping and giving up are ``step_outcome``'s.

    ``ptol``: also converged, at x and without evaluating x + dx, when the step just solved
    predicts a decrease -g.dx / 2 (the Newton decrement of the quadratic model) below ``ptol``
    relative to the cost, while the damping is negligible (mu <= ``PRED_MU_MAX``; a damped step
    under-predicts). x is then within about sqrt(2 ptol cost) whitened units of the minimum:
    the evaluation of a step whose gain no one could use is saved.
    """
    x = np.asarray(x0, dtype=float).copy()
    if solve is None:
        factor = SparseLDL()

        def solve(a, shift, rhs):
            return solve_normal(add_diagonal(a, shift), rhs, factor)

    ne = evaluate(x)
    mu = MU_START
    converged = False
    it = 0
    for it in range(1, max_iter + 1):
        a = ne.normal
        scale = damping_scale(a.diagonal())
        if ne.curvature is not None and it > 1:
            a = add_diagonal(a, clamp_curvature(ne.curvature, scale))
        while True:
            dx = solve(a, mu * scale, -ne.gradient)
            if ptol is not None and settled(-0.5 * float(ne.gradient @ dx), ne.cost, mu, ptol, ScalarOps):
                return LsqResult(x, ne.cost, it, True, ne.normal, ne.extra)
            x_new = x + dx
            ne_new = evaluate(x_new)
            step_max, x_max = (float(np.abs(dx).max()), float(np.abs(x).max())) if dx.size else (0.0, 0.0)
            accept, done, mu, gave_up = step_outcome(float(ne.cost), float(ne_new.cost), step_max, x_max, mu, xtol, ftol, ScalarOps)
            if accept:
                break
            if done:  # a negligible step rejected: x is the minimum
                return LsqResult(x, ne.cost, it, True, ne.normal, ne.extra)
            if gave_up:
                return LsqResult(x, ne.cost, it, converged, a, ne.extra)
        x, ne = x_new, ne_new
        if done:
            converged = True
            break
    return LsqResult(x, ne.cost, it, converged, ne.normal, ne.extra)


def levenberg_marquardt(
    residuals: Callable[[np.ndarray], tuple[np.ndarray, sp.csr_matrix]],
    x0: np.ndarray,
    *,
    second_order: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
    huber: float | None = None,
    max_iter: int = MAX_ITER,
    xtol: float = 1e-10,
    ftol: float = 1e-12,
) -> LsqResult:
    """Minimise sum(rho(r_k(x))) with rho quadratic (or Huber beyond ``huber``, via IRLS) by ``minimize``.

    ``residuals(x)`` returns the residual vector and its sparse Jacobian; residuals
    should be whitened (unit variance) when ``huber`` is used, so the threshold is in sigmas.
    ``second_order(x, r)``, if given, returns the diagonal of sum_k r_k d^2 r_k / dx^2,
    the term Gauss-Newton drops; adding it (kept >= 10 % of the Gauss-Newton diagonal)
    restores fast convergence where soft modes meet curved residuals (rotations).
    The result's ``extra`` is the (weighted) Jacobian at the solution.
    """

    def evaluate(x: np.ndarray) -> NormalEquations:
        r, jac = residuals(x)
        w, cost = huber_weights(r, huber)
        if w is not None:
            sw = np.sqrt(w)
            r, jac = r * sw, (sw[:, None] * jac if isinstance(jac, np.ndarray) else sp.diags(sw) @ jac)
        normal = jac.T @ jac if isinstance(jac, np.ndarray) else (jac.T @ jac).tocsr()
        curvature = None if second_order is None else second_order(x, r)  # of the weighted residuals
        return NormalEquations(cost, normal, jac.T @ r, curvature, jac)

    return minimize(evaluate, x0, max_iter=max_iter, xtol=xtol, ftol=ftol)
