"""Sparse Levenberg-Marquardt over pose unknowns, shared by every localizer.

One driver (``drive``) runs the rule for one problem (``minimize``, ``ScalarOps``) and for many in lock-step
(the planner's batch, ``BatchOps``).

Residuals and Jacobians are assembled vectorised (COO triplets); the normal equations
(J^T J + mu diag(J^T J)) dx = -J^T r are solved densely for small problems and otherwise with a
sparse factorization (``SparseFactor``: CHOLMOD's supernodal Cholesky when the optional ``cholmod`` extra is
installed, else QDLDL's LDL^T; an approximate-minimum-degree ordering and symbolic analysis reused across iterations),
so a 1000-robot swarm with range-limited sensing stays fast.

Small problems (up to ``DENSE_JACOBIAN_LIMIT`` unknowns) never touch scipy.sparse: the Jacobian is
a dense array built by ``np.bincount`` from the triplets, whose per-call overhead is a few
microseconds instead of the ~100 us of building sparse matrices, which dominated the
10-robot step. Dense algebra on bigger problems runs with one BLAS thread (``blas_threads``):
on a busy 2-core machine multi-threaded OpenBLAS is many times slower for these sizes.
"""

from __future__ import annotations

import contextlib
import functools
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, TypeVar, cast, overload

import numpy as np
import qdldl
import scipy.sparse as sp
from threadpoolctl import ThreadpoolController

DENSE_LIMIT = 64  # unknowns up to which a dense solve beats the sparse factorization (a 300x300 dense LU was ~3 ms)
DENSE_JACOBIAN_LIMIT = 64  # unknowns up to which a dense Jacobian (and dense J^T J) beats building sparse ones
PRED_MU_MAX = 1e-6  # damping up to which a step's predicted decrease stands for the undamped one (``minimize``'s ptol)
BLAS_SMALL = 96  # matrix order below which OpenBLAS stays single-threaded anyway (no limit needed)
_THREADPOOLS = ThreadpoolController()
# what ``drive`` and its rule hold per problem: a float or bool (``ScalarOps``) or a numpy array with one value per
# problem (numpy, ``BatchOps``); ``xp`` is one of those three namespaces
PerProblem = Any
_T = TypeVar("_T")


def blas_threads(size: int) -> contextlib.AbstractContextManager[object]:
    """Context limiting BLAS to one thread when dense algebra of order ``size`` follows (a no-op when small)."""
    if size < BLAS_SMALL:
        return contextlib.nullcontext()
    return cast(contextlib.AbstractContextManager[object], _THREADPOOLS.limit(limits=1, user_api="blas"))  # no types


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


def solve_normal(a: sp.spmatrix | np.ndarray, b: np.ndarray, factor: SparseFactor | None = None) -> np.ndarray:
    """Solve the symmetric positive definite system a x = b: dense up to ``DENSE_LIMIT`` unknowns, else by a
    sparse factorization (``SparseFactor``; pass one to reuse its symbolic analysis across calls with the same pattern)."""
    if isinstance(a, np.ndarray) or a.shape[0] <= DENSE_LIMIT:
        return np.linalg.solve(dense(a), b)
    return (factor or SparseFactor()).solve(a, b)


@functools.cache
def cholmod_module() -> Any | None:
    """cvxopt's CHOLMOD binding when installed (the ``cholmod`` extra), else None."""
    try:
        from cvxopt import cholmod  # noqa: PLC0415 - optional dependency, loaded on first use
    except ImportError:
        return None
    return cholmod


def sparse_backend() -> str:
    """The sparse factorization ``SparseFactor`` uses by default: ``"cholmod"`` when installed, else ``"qdldl"``."""
    return "cholmod" if cholmod_module() is not None else "qdldl"


class _Qdldl:
    """QDLDL's LDL^T (approximate-minimum-degree ordering): the default, always installed."""

    def __init__(self, upper: sp.csc_matrix) -> None:
        self._solver = qdldl.Solver(upper, upper=True)

    def refactor(self, upper: sp.csc_matrix) -> None:
        self._solver.update(upper, upper=True)

    def solve(self, b: np.ndarray) -> np.ndarray:
        return cast(np.ndarray, self._solver.solve(b))


class _Cholmod:
    """CHOLMOD's supernodal Cholesky (approximate-minimum-degree ordering, dense BLAS kernels on supernodes).

    The matrix object is built once per pattern; a refactorization only replaces its values (in the upper
    triangle's sorted CSC order, which is the matrix's own). Raises ``ArithmeticError`` when the matrix is
    not positive definite.
    """

    def __init__(self, upper: sp.csc_matrix) -> None:
        from cvxopt import cholmod, matrix, spmatrix  # noqa: PLC0415 - optional dependency, present when this class is used
        self._cholmod, self._matrix = cholmod, matrix
        size = upper.shape[0]
        cols = np.repeat(np.arange(size, dtype=np.int64), np.diff(upper.indptr))
        self._a = spmatrix(matrix(upper.data), matrix(upper.indices.astype(np.int64)), matrix(cols), (size, size))
        self._cholmod.options["supernodal"] = 2
        self._f = self._cholmod.symbolic(self._a, uplo="U")
        self._numeric()

    def _numeric(self) -> None:
        self._cholmod.options["supernodal"] = 2
        self._cholmod.numeric(self._a, self._f)

    def refactor(self, upper: sp.csc_matrix) -> None:
        self._a.V = self._matrix(upper.data)
        self._numeric()

    def solve(self, b: np.ndarray) -> np.ndarray:
        x = self._matrix(b)
        self._cholmod.solve(self._f, x)
        return np.array(x).reshape(b.shape)


class SparseFactor:
    """Factorization of sparse symmetric positive definite matrices, keeping its ordering and symbolic analysis while
    the sparsity pattern stays the same.

    ``backend``: ``"cholmod"`` (CHOLMOD's supernodal Cholesky through cvxopt, the optional ``cholmod`` extra),
    ``"qdldl"`` (QDLDL's LDL^T, always installed) or None (CHOLMOD when installed). A matrix CHOLMOD finds not
    positive definite is factorized by QDLDL instead.

    Levenberg-Marquardt factorizes J^T J + mu D with one pattern at every iteration, so the numeric
    refactorization is what counts. QDLDL's is 2.5-3x faster than a fresh factorization of its own (300
    unknowns: 0.34 / 0.95 ms; SciPy's SuperLU 4.1 ms). CHOLMOD's supernodal refactorization is 3-7x faster
    than QDLDL's on the topology of range-limited swarms (357 unknowns: 0.32 / 1.07 ms; 1497: 4.6 / 26 ms;
    2997: 27 / 196 ms, docs/benchmarks.md), whose factors are dense enough for BLAS to pay.
    """

    def __init__(self, backend: str | None = None) -> None:
        if backend not in (None, "cholmod", "qdldl"):
            raise ValueError(f"unknown sparse backend {backend!r} (cholmod or qdldl)")
        if backend == "cholmod" and cholmod_module() is None:
            raise ImportError("the cholmod backend needs cvxopt: pip install 'inchworm-swarm[cholmod]'")
        self.backend = backend or sparse_backend()
        self._factor: _Qdldl | _Cholmod | None = None
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
        if same_pattern and self._factor is not None:
            try:
                self._factor.refactor(upper)
            except ArithmeticError:  # not positive definite for CHOLMOD's Cholesky: QDLDL's LDL^T
                self._factor = _Qdldl(upper)
        else:
            self._factor = self._new(upper)
        return self._factor.solve(b)

    def apply(self, b: np.ndarray) -> np.ndarray:
        """a^-1 b for the matrix ``a`` factorized last (a preconditioner for systems near it)."""
        if self._factor is None:
            raise ValueError("nothing factorized yet")
        return self._factor.solve(b)

    def _new(self, upper: sp.csc_matrix) -> _Qdldl | _Cholmod:
        if self.backend == "cholmod":
            with contextlib.suppress(ArithmeticError):
                return _Cholmod(upper)
        return _Qdldl(upper)


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


# The Levenberg-Marquardt rule, defined once for ``drive``, which runs one problem (``minimize``) or many in lock-step
# (the planner's ``batch``): the damping and its scale, the clamp of the second-order term, acceptance and convergence.
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
    return cast(np.ndarray, np.maximum(diagonal, DIAG_FLOOR))


def clamp_curvature(curvature: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """The second-order term C kept >= -``CURVATURE_FLOOR`` D, so A + C + mu D stays positive definite."""
    return cast(np.ndarray, np.maximum(curvature, -CURVATURE_FLOOR * scale))


class ScalarOps:
    """The operations of the rule and of ``drive`` for one problem held in Python floats and bools (numpy's cost
    ~1 us per call on scalars, which added ~10 % to a 10-robot step): the same expressions as ``BatchOps``."""

    batched = False
    maximum = staticmethod(max)
    isfinite = staticmethod(math.isfinite)
    any = staticmethod(bool)
    quiet = staticmethod(contextlib.nullcontext)  # floats raise no numpy warnings

    @staticmethod
    def where(condition: bool, a: float, b: float) -> float:
        return a if condition else b

    @staticmethod
    def logical_not(a: bool) -> bool:
        return not a

    @staticmethod
    def full(like: float, value: float) -> float:
        return value

    @staticmethod
    def largest(a: np.ndarray) -> float:
        """max |a| (0 for no unknowns)."""
        return float(np.abs(a).max()) if a.size else 0.0

    @staticmethod
    def keep(mask: bool, a: _T, b: _T) -> _T:
        """``a`` where ``mask``, else ``b`` (points, steps and states)."""
        return a if mask else b


class BatchOps:
    """The same operations for many problems at once: numpy arrays with the problems on their first axis; a state
    is a dict of such arrays. ``keep`` overwrites ``a`` in place where ``mask`` is False (no fresh arrays:
    they cost page faults at every iteration)."""

    batched = True
    quiet = staticmethod(functools.partial(np.errstate, invalid="ignore"))  # finished problems may hold inf - inf
    maximum = staticmethod(np.maximum)
    isfinite = staticmethod(np.isfinite)
    any = staticmethod(np.any)
    where = staticmethod(np.where)
    logical_not = staticmethod(np.logical_not)

    @staticmethod
    def full(like: np.ndarray, value: float) -> np.ndarray:
        return np.full(np.shape(like), value)

    @staticmethod
    def largest(a: np.ndarray) -> np.ndarray:
        """max |a| of each problem."""
        return cast(np.ndarray, np.max(np.abs(a), axis=tuple(range(1, a.ndim))))

    @staticmethod
    def keep(mask: np.ndarray, a: Any, b: Any) -> Any:  # arrays, or dicts of them (states); ``b`` may be a float
        back = np.flatnonzero(~mask)
        if back.size:
            if isinstance(a, dict):
                for key, value in a.items():
                    value[back] = b[key][back]
            else:
                a[back] = b if np.isscalar(b) else b[back]
        return a


def step_outcome(cost: PerProblem, cost_new: PerProblem, step_max: PerProblem, x_max: PerProblem, mu: PerProblem, xtol: float,
                 ftol: float, xp: Any = np) -> tuple[PerProblem, PerProblem, PerProblem, PerProblem]:
    """What a trial step does: (accepted, converged, next damping, given up), per problem.

    Arguments are arrays (one value per problem; ``xp`` numpy or ``BatchOps``) or floats (``xp`` = ``ScalarOps``).
    ``step_max`` is the step's largest |component|, ``x_max`` that of the point it started from. A step is
    accepted when finite and not raising the cost beyond rounding (``ACCEPT_SLACK``); the damping is then
    divided by ``MU_FACTOR`` (floor ``MU_MIN``), else multiplied. Converged: an accepted step below
    ``xtol`` (1 + max |x|) or lowering the cost by less than ``ftol`` of it (the new point is the solution),
    or a rejected step below ``xtol`` (1 + max |x|): the problem sits at its minimum, where rounding decides
    the cost (the old point is the solution). Given up: a rejected step that took the damping beyond ``MU_MAX``.
    """
    accept = xp.isfinite(cost_new) & (cost_new <= cost * (1 + ACCEPT_SLACK) + _TINY)  # & and |: bools or bool arrays
    gain_small = cost - cost_new <= ftol * xp.maximum(cost, _TINY)
    converged = (step_max <= xtol * (1.0 + x_max)) | (accept & gain_small)
    mu_next = xp.where(accept, xp.maximum(mu / MU_FACTOR, MU_MIN), mu * MU_FACTOR)
    gave_up = xp.logical_not(accept | converged) & (mu_next > MU_MAX)
    return accept, converged, mu_next, gave_up


def settled(predicted: PerProblem, cost: PerProblem, mu: PerProblem, ptol: float, xp: Any = np) -> PerProblem:
    """Converged before the step (``minimize``'s ``ptol``): its predicted decrease -g.dx / 2 below ``ptol`` of the
    cost while the damping is negligible (mu <= ``PRED_MU_MAX``; a damped step under-predicts)."""
    return (mu <= PRED_MU_MAX) & (predicted <= ptol * cost)


COMPACT_BELOW = 0.5  # ``drive`` drops finished problems from its work set once fewer than this fraction is active


def drive(problem: Any, x0: np.ndarray, xtol: float, ftol: float, ptol: float | None = None, max_iter: int = MAX_ITER,
          xp: Any = BatchOps) -> tuple[np.ndarray, PerProblem, PerProblem, dict[str, Any]]:
    """The Levenberg-Marquardt driver of every localizer: one problem (``xp=ScalarOps``, ``minimize``) or many in
    lock-step (``xp=BatchOps``, the planner's batch: ``x0`` (B, ...) with the problems on the first axis).

    ``problem.evaluate(x, slot)`` returns the state at x, a dict holding at least ``cost``, kept in ``slot`` (0 or
    1: the current point's state and the trial's coexist); ``problem.step(state, mu, curved)`` the damped step
    (A + C + mu D) dx = -g and its predicted decrease -g.dx / 2, with the second-order term C only where
    ``curved`` (from a problem's second iteration: the first is Gauss-Newton); batched, ``problem.subset(index)``
    the problem restricted to some of its problems. Every problem starts at ``MU_START``; each trial step's
    acceptance, convergence, next damping and giving up are ``step_outcome``'s; with ``ptol`` a problem whose
    step predicts a negligible decrease (``settled``) stops where it is, without evaluating the step; a problem
    fails after ``max_iter`` accepted steps or when it gives up, and never starts where its cost is not finite.
    A batched problem that finished leaves the work set once fewer than ``COMPACT_BELOW`` of it are active (checked
    before each step and before each trial point is evaluated: the problems a step settled are not evaluated there).

    Returns (x, converged, iterations, state): iterations counts the iterations started (accepted steps, plus
    one when the last trial was not accepted), state is the final point's (of one problem; batched, of every
    problem: the rows of those that left the work set are kept as they left it).
    """
    x = np.array(x0, dtype=float, copy=True)
    st, slot = problem.evaluate(x, 0), 1
    cost = st["cost"]
    mu, iterations = xp.full(cost, MU_START), xp.full(cost, 0)
    active = xp.isfinite(cost) & (max_iter > 0)  # & and |: bools or bool arrays, as the problems are held
    converged = active & False
    accepted = xp.logical_not(converged)  # the last trial's acceptance (none yet)
    if xp.batched:
        full_x, full_converged, work = x, converged.copy(), np.arange(len(x))
        full_st: dict[str, np.ndarray] | None = None

    def sparse() -> bool:  # batched, and fewer than ``COMPACT_BELOW`` of the work set active
        return bool(xp.batched and np.count_nonzero(active) < COMPACT_BELOW * len(work))

    def compact(dx: np.ndarray | None = None) -> np.ndarray | None:
        """Drop the finished problems from the work set (their rows stay in the full arrays); ``dx`` restricted alike."""
        nonlocal work, x, mu, active, iterations, converged, accepted, problem, st, full_st
        full_x[work], full_converged[work] = x, converged
        full_st = _scatter_state(full_st, st, work)
        keep = np.flatnonzero(active)
        work, x, mu, active, iterations, converged, accepted = (a[keep] for a in (work, x, mu, active, iterations, converged, accepted))
        problem = problem.subset(keep)
        st = {key: value[keep] for key, value in st.items()}
        return None if dx is None else dx[keep]

    while xp.any(active):
        if sparse():
            compact()
        dx, predicted = problem.step(st, mu, iterations > 0)
        if ptol is not None:  # converged before the step
            early = active & settled(predicted, st["cost"], mu, ptol, xp)
            converged = converged | early
            accepted = accepted & xp.logical_not(early)
            active = active & xp.logical_not(early)
            if not xp.any(active):
                break
            if sparse():  # most settled: no trial point for them
                dx = compact(dx)
        x_new = x + xp.keep(active, dx, 0.0)
        new = problem.evaluate(x_new, slot)
        with xp.quiet():
            accepted, done, mu, gave_up = step_outcome(st["cost"], new["cost"], xp.largest(dx), xp.largest(x), mu, xtol, ftol, xp)
        converged = converged | (done & active)
        iterations = iterations + accepted
        x, st, slot = xp.keep(accepted, x_new, x), xp.keep(accepted, new, st), 1 - slot
        # finished: converged, or failed (given up, or out of accepted steps)
        active = active & xp.logical_not(done | gave_up | (iterations >= max_iter))
    started = iterations + xp.logical_not(accepted)
    if xp.batched:
        full_x[work], full_converged[work] = x, converged
        return full_x, full_converged, started, _scatter_state(full_st, st, work)
    return x, converged, started, st


def _scatter_state(full: dict[str, np.ndarray] | None, st: dict[str, np.ndarray], work: np.ndarray) -> dict[str, np.ndarray]:
    """The batch's state with the rows ``work`` from the work set's ``st`` (``full`` None: ``st`` is the whole batch's,
    as before the first compaction; its arrays are no longer written once the work set has its own problem)."""
    if full is None:
        return st
    for key, value in st.items():
        full[key][work] = value
    return full


class _NormalProblem:
    """One problem given by its normal equations, for ``drive``: ``minimize``'s callbacks."""

    def __init__(self, evaluate: Callable[[np.ndarray], NormalEquations],
                 solve: Callable[[sp.spmatrix | np.ndarray, np.ndarray, np.ndarray], np.ndarray]) -> None:
        self._evaluate, self._solve = evaluate, solve
        self._system: tuple[Any, ...] = (None, None, None, None)  # (state, curved, A (+ C), D) of the last step: rejected trials reuse it

    def evaluate(self, x: np.ndarray, slot: int) -> dict[str, Any]:
        ne = self._evaluate(x)
        return {"cost": float(ne.cost), "ne": ne}

    def step(self, st: dict[str, Any], mu: float, curved: bool) -> tuple[np.ndarray, float]:
        ne = st["ne"]
        if self._system[0] is not ne or self._system[1] != curved:
            a = ne.normal
            scale = damping_scale(a.diagonal())
            if ne.curvature is not None and curved:
                a = add_diagonal(a, clamp_curvature(ne.curvature, scale))
            self._system = (ne, curved, a, scale)
        _, _, a, scale = self._system
        dx = self._solve(a, mu * scale, -ne.gradient)
        return dx, -0.5 * float(ne.gradient @ dx)


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
    """Levenberg-Marquardt on the normal equations ``evaluate(x)`` returns: ``drive`` with one problem.

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
    if solve is None:
        factor = SparseFactor()

        def solve(a: sp.spmatrix | np.ndarray, shift: np.ndarray, rhs: np.ndarray) -> np.ndarray:
            return solve_normal(add_diagonal(a, shift), rhs, factor)

    x, converged, iterations, st = drive(_NormalProblem(evaluate, solve), x0, xtol, ftol, ptol, max_iter, ScalarOps)
    ne = st["ne"]
    return LsqResult(x, ne.cost, int(iterations), bool(converged), ne.normal, ne.extra)


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
