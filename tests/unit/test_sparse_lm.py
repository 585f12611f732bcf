"""Known answers for the shared least-squares machinery (coordinator/localization/sparse_lm.py).

Each answer is worked out by hand in the test's docstring (small linear or Huber problems with a
closed-form minimiser, the Rosenbrock valley, column maps of a few robots), not by running the code.
"""

from __future__ import annotations

import contextlib
import math

import numpy as np
import pytest
import scipy.sparse as sp
from threadpoolctl import ThreadpoolController

import coordinator.localization.sparse_lm as sparse_lm
from coordinator.localization.sparse_lm import (
    BLAS_SMALL,
    DENSE_JACOBIAN_LIMIT,
    DENSE_LIMIT,
    NormalEquations,
    PoseLayout,
    SparseFactor,
    blas_threads,
    dense,
    jacobian,
    levenberg_marquardt,
    minimize,
    solve_normal,
)


def blas_thread_counts() -> list[int]:
    """Threads of numpy's BLAS (the one ``np.linalg`` runs on; SciPy may load its own copy)."""
    infos = ThreadpoolController().select(user_api="blas").info()
    return [info["num_threads"] for info in infos if "numpy" in info["filepath"]]


def test_blas_threads_limits_only_large_dense_algebra():
    """Below order 96 nothing is limited (a no-op context); from 96 on, numpy's BLAS runs one thread
    even when the caller allowed two."""
    assert BLAS_SMALL == 96
    assert isinstance(blas_threads(95), contextlib.nullcontext)
    assert not isinstance(blas_threads(96), contextlib.nullcontext)
    if not blas_thread_counts():
        pytest.skip("no BLAS library visible to threadpoolctl")
    with ThreadpoolController().limit(limits=2, user_api="blas"):
        outside = blas_thread_counts()
        with blas_threads(96):
            assert set(blas_thread_counts()) == {1}
        with blas_threads(95):
            assert blas_thread_counts() == outside


def test_pose_layout_columns_pack_and_unpack():
    """Free masks position (T, F, T), heading (F, T, T): per robot the free components are
    (x, y), (theta), (x, y, theta), numbered in row order: columns [[0, 1, -1], [-1, -1, 2], [3, 4, 5]],
    6 unknowns. Packing takes exactly those components; unpacking writes them back over ``fixed``."""
    layout = PoseLayout(np.array([True, False, True]), np.array([False, True, True]))
    assert layout.cols.tolist() == [[0, 1, -1], [-1, -1, 2], [3, 4, 5]]
    assert layout.size == 6 and type(layout.size) is int
    poses = np.arange(9.0).reshape(3, 3) + 1  # [[1,2,3],[4,5,6],[7,8,9]]
    assert layout.pack(poses).tolist() == [1, 2, 6, 7, 8, 9]
    fixed = -np.ones((3, 3), int)
    out = layout.unpack(np.array([10.5, 20, 30, 40, 50, 60]), fixed)
    assert out.dtype == float and out.tolist() == [[10.5, 20, -1], [-1, -1, 30], [40, 50, 60]]
    assert fixed.tolist() == (-np.ones((3, 3))).tolist()  # the fixed poses are not written to
    fixed_float = np.zeros((3, 3))
    layout.unpack(np.arange(6.0), fixed_float)
    assert not fixed_float.any()  # nor when they already are floats
    none = PoseLayout(np.zeros(2, bool), np.zeros(2, bool))
    assert none.size == 0 and (none.cols == -1).all() and none.pack(poses[:2]).shape == (0,)


@pytest.mark.parametrize("n_cols", [3, DENSE_JACOBIAN_LIMIT, DENSE_JACOBIAN_LIMIT + 1])
def test_jacobian_sums_duplicates_and_drops_fixed_columns(n_cols):
    """Triplets (0,0,1), (0,0,2), (1,2,5), (1,-1,7), (2,1,-3): entry (0,0) = 1 + 2 = 3 (duplicates
    add), (1,2) = 5, (2,1) = -3, the column -1 entry vanishes. Dense up to 64 columns, sparse above."""
    rows, cols, vals = np.array([0, 0, 1, 1, 2]), np.array([0, 0, 2, -1, 1]), np.array([1.0, 2, 5, 7, -3])
    jac = jacobian(3, n_cols, rows, cols, vals)
    assert isinstance(jac, np.ndarray) == (n_cols <= 64)
    expected = np.zeros((3, n_cols))
    expected[0, 0], expected[1, 2], expected[2, 1] = 3, 5, -3
    assert dense(jac).shape == (3, n_cols)
    np.testing.assert_array_equal(dense(jac), expected)


@pytest.mark.parametrize("size", [5, DENSE_LIMIT, DENSE_LIMIT + 1, 200])
def test_solve_normal_solves_a_tridiagonal_system(size):
    """A = tridiag(-1, 2, -1) + I (SPD) and b = A x for x_k = k: the solve returns x, dense or sparse."""
    a = sp.diags([-np.ones(size - 1), 3 * np.ones(size), -np.ones(size - 1)], [-1, 0, 1]).tocsr()
    x = np.arange(size, dtype=float)
    b = a @ x
    np.testing.assert_allclose(solve_normal(a, b), x, rtol=1e-10, atol=1e-9)
    np.testing.assert_allclose(solve_normal(a.toarray(), b), x, rtol=1e-10, atol=1e-9)


def spd_tridiagonal(size: int, scale: float = 1.0) -> sp.csr_matrix:
    """scale * tridiag(-1, 3, -1): symmetric, strictly diagonally dominant, so positive definite."""
    return (scale * sp.diags([-np.ones(size - 1), 3 * np.ones(size), -np.ones(size - 1)], [-1, 0, 1])).tocsr()


BACKENDS = ("cholmod", "qdldl")


@pytest.mark.parametrize("backend", BACKENDS)
def test_sparse_factor_reuses_its_analysis_only_for_the_same_pattern(backend):
    """One factor object solving, in turn: A (tridiagonal, 100 unknowns), 2 A (same pattern: numeric
    update), A + a corner entry (new pattern: fresh analysis), and A again. Each answer is x with
    x_k = k, since b is built as A x; a stale factorization would return x / 2 or miss the corner."""
    size = 100
    x = np.arange(size, dtype=float)
    corner = sp.csr_matrix(([0.5, 0.5], ([0, size - 1], [size - 1, 0])), shape=(size, size))
    factor = SparseFactor(backend)
    solvers = []
    for a in (spd_tridiagonal(size), spd_tridiagonal(size, 2.0), (spd_tridiagonal(size) + corner).tocsr(), spd_tridiagonal(size)):
        np.testing.assert_allclose(factor.solve(a, a @ x), x, rtol=1e-10, atol=1e-9)
        solvers.append(factor._factor)
        np.testing.assert_allclose(solve_normal(a, a @ x, factor), x, rtol=1e-10, atol=1e-9)
    # The analysis (the backend's factor object) is kept for 2 A and replaced for each new pattern.
    assert solvers[1] is solvers[0] and solvers[2] is not solvers[1] and solvers[3] is not solvers[2]
    assert type(solvers[0]).__name__ == {"cholmod": "_Cholmod", "qdldl": "_Qdldl"}[backend]


@pytest.mark.parametrize("backend", BACKENDS)
def test_sparse_factor_uses_only_the_upper_triangle_of_unsorted_input(backend):
    """A CSC matrix with unsorted row indices (built column by column in reverse) solves like its
    sorted copy: the factor sorts the upper triangle it keeps."""
    size = 80
    a = spd_tridiagonal(size).tocoo()
    order = np.argsort(-a.row, kind="stable")
    unsorted = sp.csc_matrix((a.data[order], (a.row[order], a.col[order])), shape=a.shape)
    unsorted.has_sorted_indices = False
    x = np.linspace(-1, 1, size)
    np.testing.assert_allclose(SparseFactor(backend).solve(unsorted, spd_tridiagonal(size) @ x), x, rtol=1e-10, atol=1e-12)


def geometric_normal_matrix(n: int, seed: int = 0) -> sp.csr_matrix:
    """J^T J + 1e-3 I of 2D range-limited relative-position observations among ``n`` robots (2n unknowns):
    every pair closer than 0.5 m in a 0.1 m-spaced square blob, like a swarm's topology problem (dense factors)."""
    rng = np.random.default_rng(seed)
    side = math.ceil(math.sqrt(n))
    p = 0.1 * np.stack(np.unravel_index(np.arange(n), (side, side)), axis=1) + rng.normal(0, 0.02, (n, 2))
    i, j = np.nonzero(np.triu(np.hypot(*(p[:, None] - p[None]).transpose(2, 0, 1)) < 0.5, 1))
    m = len(i)
    rows = np.repeat(np.arange(2 * m), 2)
    cols = np.stack([np.stack([2 * i, 2 * j], 1), np.stack([2 * i + 1, 2 * j + 1], 1)], 1).reshape(-1)
    jac = sp.csr_matrix((np.tile([1.0, -1.0], 2 * m) * rng.uniform(0.5, 2.0, 4 * m), (rows, cols)), shape=(2 * m, 2 * n))
    return (jac.T @ jac + 1e-3 * sp.eye(2 * n)).tocsr()


def test_cholmod_and_qdldl_agree_on_a_swarm_sized_problem():
    """300 robots (600 unknowns, ~40 neighbours each): both backends solve to 1e-10 relative, also after a
    numeric refactorization with a changed diagonal (the Levenberg-Marquardt damping)."""
    a = geometric_normal_matrix(300)
    b = np.random.default_rng(1).normal(size=a.shape[0])
    factors = {name: SparseFactor(name) for name in BACKENDS}
    for shift in (0.0, 0.5):
        shifted = (a + shift * sp.eye(a.shape[0])).tocsr()
        x = {name: f.solve(shifted, b) for name, f in factors.items()}
        np.testing.assert_allclose(shifted @ x["cholmod"], b, rtol=0, atol=1e-9 * np.abs(b).max())
        np.testing.assert_allclose(x["cholmod"], x["qdldl"], rtol=1e-10, atol=1e-10 * np.abs(x["qdldl"]).max())


def test_cholmod_hands_a_matrix_that_is_not_positive_definite_to_qdldl():
    """A symmetric quasi-definite matrix (blocks [[2, 1], [1, -3]] along a 100-unknown diagonal, coupled) has
    no Cholesky factor: the factor answers it with QDLDL's LDL^T, at first and after a refactorization."""
    size = 100
    diag = np.where(np.arange(size) % 2 == 0, 2.0, -3.0)
    off = np.where(np.arange(size - 1) % 2 == 0, 1.0, 0.1)
    a = sp.diags([off, diag, off], [-1, 0, 1]).tocsr()
    x = np.linspace(-2, 2, size)
    factor = SparseFactor("cholmod")
    for scale in (1.0, 2.0):
        np.testing.assert_allclose(factor.solve(scale * a, scale * a @ x), x, rtol=1e-10, atol=1e-10)
        assert type(factor._factor).__name__ == "_Qdldl"


def test_sparse_factor_names_a_bad_or_missing_backend(monkeypatch):
    with pytest.raises(ValueError, match="unknown sparse backend 'umfpack'"):
        SparseFactor("umfpack")
    monkeypatch.setattr(sparse_lm, "cholmod_module", lambda: None)
    assert sparse_lm.sparse_backend() == "qdldl" and SparseFactor().backend == "qdldl"
    with pytest.raises(ImportError, match=r"inchworm-swarm\[cholmod\]"):
        SparseFactor("cholmod")


def location_problem(y: np.ndarray, sparse: bool = False):
    """Residuals r_i(x) = x - y_i (one unknown), Jacobian a column of ones."""

    def residuals(x):
        jac = np.ones((len(y), 1))
        return x[0] - y, sp.csr_matrix(jac) if sparse else jac

    return residuals


@pytest.mark.parametrize("sparse", [False, True])
def test_least_squares_mean(sparse):
    """Quadratic loss on y = (0, 0, 0, 10): the minimiser is the mean 2.5, the cost
    0.5 (3 * 2.5^2 + 7.5^2) = 37.5 and J^T J = 4; a linear problem converges in at most 2 steps."""
    out = levenberg_marquardt(location_problem(np.array([0.0, 0, 0, 10]), sparse), np.array([0.0]))
    assert out.converged and out.iterations <= 2
    np.testing.assert_allclose(out.x, [2.5], atol=1e-9)
    assert out.cost == pytest.approx(37.5, rel=1e-9)
    np.testing.assert_allclose(dense(out.normal_matrix), [[4.0]], rtol=1e-9)
    np.testing.assert_array_equal(dense(out.extra), np.ones((4, 1)))


@pytest.mark.parametrize("sparse", [False, True])
def test_huber_location_estimate(sparse):
    """Huber loss (threshold 1) on y = (0, 0, 0, 10): with three residuals inside the threshold and the
    outlier beyond it, the stationarity condition is 3 x - 1 = 0, so x = 1/3; the cost is
    3 * 0.5 (1/3)^2 + (|1/3 - 10| - 0.5) = 28/3, and the IRLS normal matrix sum w_i is
    3 + 1 / |1/3 - 10| = 3 + 3/29."""
    out = levenberg_marquardt(location_problem(np.array([0.0, 0, 0, 10]), sparse), np.array([0.0]), huber=1.0)
    assert out.converged
    np.testing.assert_allclose(out.x, [1 / 3], atol=1e-8)
    assert out.cost == pytest.approx(28 / 3, rel=1e-9)
    np.testing.assert_allclose(dense(out.normal_matrix), [[3 + 3 / 29]], rtol=1e-7)
    # The returned Jacobian is the Huber-weighted one: sqrt(w_i) = 1, 1, 1, sqrt(3 / 29).
    np.testing.assert_allclose(dense(out.extra)[:, 0], [1, 1, 1, np.sqrt(3 / 29)], rtol=1e-7)


def rosenbrock(x):
    """r = (10 (x1 - x0^2), 1 - x0): cost 0 only at (1, 1)."""
    r = np.array([10 * (x[1] - x[0] ** 2), 1 - x[0]])
    jac = np.array([[-20 * x[0], 10.0], [-1.0, 0.0]])
    return r, jac


def test_rosenbrock_valley_is_followed_to_its_minimum():
    """From the classic start (-1.2, 1) the minimum (1, 1), cost 0, is reached; J^T J there is
    [[-20, -1], [10, 0]] [[-20, 10], [-1, 0]] = [[401, -200], [-200, 100]]."""
    out = levenberg_marquardt(rosenbrock, np.array([-1.2, 1.0]))
    assert out.converged and out.iterations < 100
    np.testing.assert_allclose(out.x, [1, 1], atol=1e-6)
    assert out.cost < 1e-12
    np.testing.assert_allclose(out.normal_matrix, [[401, -200], [-200, 100]], rtol=1e-5)


def test_iteration_cap_is_reported():
    """Three iterations cannot reach the Rosenbrock minimum: 3 iterations, not converged, and the start
    point's cost 0.5 (10^2 (1 - 1.44)^2 + 2.2^2) = 12.1 has decreased."""
    start = np.array([-1.2, 1.0])
    assert 0.5 * float(rosenbrock(start)[0] @ rosenbrock(start)[0]) == pytest.approx(12.1)
    out = levenberg_marquardt(rosenbrock, start, max_iter=3)
    assert out.iterations == 3 and not out.converged
    assert 0 < out.cost < 12.1
    assert not np.allclose(out.x, [1, 1], atol=1e-3)


def test_no_acceptable_step_gives_up_after_raising_the_damping_to_1e10():
    """A cost that is NaN everywhere but the start: every trial step is refused and the damping mu goes
    1e-8, 1e-7, ..., 1e10 (19 trials) before exceeding 1e10; the start point comes back, unconverged,
    after one iteration, with 1 + 19 residual evaluations."""
    calls = []

    def residuals(x):
        calls.append(x.copy())
        r = np.array([x[0] - 3.0]) if x[0] == 0 else np.array([np.nan])
        return r, np.ones((1, 1))

    out = levenberg_marquardt(residuals, np.array([0.0]))
    assert (out.x.tolist(), out.iterations, out.converged) == ([0.0], 1, False)
    assert out.cost == pytest.approx(4.5)
    assert dense(out.normal_matrix).tolist() == [[1.0]] and dense(out.extra).tolist() == [[1.0]]
    assert len(calls) == 20
    # The trial steps solve (1 + mu) dx = 3: dx = 3 / (1 + mu) for mu = 1e-8 ... 1e10.
    np.testing.assert_allclose([c[0] for c in calls[1:]], 3 / (1 + 10.0 ** np.arange(-8, 11)), rtol=1e-9)


def test_damping_decreases_after_accepted_steps():
    """The linear problem r = x - 3 with J^T J = 1: the first step at mu = 1e-8 is accepted, dx =
    3 / (1 + 1e-8); the next solve uses mu / 10 = 1e-9: x + (3 - x) / (1 + 1e-9)."""
    calls = []

    def residuals(x):
        calls.append(x.copy())
        return np.array([x[0] - 3.0]), np.ones((1, 1))

    out = levenberg_marquardt(residuals, np.array([0.0]), xtol=0.0, ftol=-1.0, max_iter=2)
    x1 = 3 / (1 + 1e-8)
    assert calls[1][0] == pytest.approx(x1, rel=1e-15)
    assert calls[2][0] == pytest.approx(x1 + (3 - x1) / (1 + 1e-9), rel=1e-15)
    assert out.iterations == 2


def test_first_step_is_gauss_newton_then_the_second_order_term_is_clamped():
    """r(x) = x^2 - 4 from x0 = 3, with a second-order diagonal of -1e6 (it would make J^T J + S
    negative). Iteration 1 is a Gauss-Newton step: J = 6, r = 5, (36 (1 + 1e-8)) dx = -30, so
    x1 = 3 - 30 / (36 (1 + 1e-8)) = 2.1666...; accepted (r = 0.6944, cost 0.2411), mu -> 1e-9.
    Iteration 2 adds the term clamped at -0.9 J^T J: J = 2 x1, g = J r(x1), the system is
    0.1 J^2 + 1e-9 J^2, so the trial is x1 - g / (J^2 (0.1 + 1e-9)) = x1 - 10 r / J (ten Gauss-Newton
    steps: x = 0.564, cost 6.8, refused). Unclamped it would step the other way by about g / 1e6.
    The minimiser x = 2 is reached all the same."""
    trials = []

    def residuals(x):
        trials.append(float(x[0]))
        return np.array([x[0] ** 2 - 4]), np.array([[2 * x[0]]])

    out = levenberg_marquardt(residuals, np.array([3.0]), second_order=lambda x, r: np.array([-1e6]))
    x1 = 3 - 30 / (36 * (1 + 1e-8))
    assert trials[1] == pytest.approx(x1, rel=1e-14)
    j, r = 2 * x1, x1**2 - 4
    assert trials[2] == pytest.approx(x1 - j * r / (j * j * (0.1 + 1e-9)), rel=1e-12)
    assert trials[2] == pytest.approx(0.5644, abs=1e-3)
    np.testing.assert_allclose(out.x, [2.0], atol=1e-6)
    assert out.converged and out.cost < 1e-10


def test_second_order_term_keeps_the_minimiser_of_a_curved_residual():
    """r(x) = (x^2 - 4, 0.1 x): d/dx 0.5 |r|^2 = 2 x (x^2 - 4) + 0.01 x = 0 at x^2 = 3.995; the
    second-order term r_0 d^2 r_0 / dx^2 = 2 r_0 changes the steps, not the minimiser; J^T J there
    is 4 x^2 + 0.01 = 15.99."""

    def residuals(x):
        return np.array([x[0] ** 2 - 4, 0.1 * x[0]]), np.array([[2 * x[0]], [0.1]])

    plain = levenberg_marquardt(residuals, np.array([3.0]))
    newton = levenberg_marquardt(residuals, np.array([3.0]), second_order=lambda x, r: np.array([2 * r[0]]))
    for out in (plain, newton):
        assert out.converged
        np.testing.assert_allclose(out.x, [np.sqrt(3.995)], rtol=1e-7)
        np.testing.assert_allclose(out.normal_matrix, [[15.99]], rtol=1e-6)


def test_pack_ignores_fixed_trailing_components():
    """Position free for both robots, heading free for robot 0 only: columns [[0, 1, 2], [3, 4, -1]];
    packing [[1, 2, 3], [4, 5, 6]] gives [1, 2, 3, 4, 5] (robot 1's heading 6 is fixed, not packed)."""
    layout = PoseLayout(np.array([True, True]), np.array([True, False]))
    assert layout.cols.tolist() == [[0, 1, 2], [3, 4, -1]]
    assert layout.pack(np.array([[1.0, 2, 3], [4, 5, 6]])).tolist() == [1, 2, 3, 4, 5]


def test_sparse_normal_matrix_is_csr():
    """With a sparse Jacobian the returned J^T J is a CSR matrix (the type ``LsqResult`` documents)."""
    out = levenberg_marquardt(location_problem(np.array([1.0, 2.0]), sparse=True), np.array([0.0]))
    assert sp.issparse(out.normal_matrix) and out.normal_matrix.format == "csr"
    assert out.normal_matrix.toarray().tolist() == [[2.0]]


def test_default_iteration_cap_is_100():
    """r(x) = exp(-x) has its infimum at x = +inf: each undamped Gauss-Newton step is dx = -r / r' = 1, so
    the cost exp(-2x) / 2 keeps falling by a constant factor and neither stopping test fires (once
    J^T J = exp(-2x) drops under the 1e-12 diagonal floor the damping shortens the steps, which
    still gain a constant fraction): the default cap stops it after 100 iterations, unconverged."""

    def residuals(x):
        return np.exp(-x), -np.exp(-x)[:, None]

    out = levenberg_marquardt(residuals, np.array([0.0]))
    assert (out.iterations, out.converged) == (100, False)
    assert out.x[0] > 14  # exp(-28) < 1e-12: well past the undamped phase


def test_zero_iterations_return_the_start():
    """max_iter = 0: no step is taken; the start point (as floats), its cost 0.5 * 3^2 and 0 iterations,
    not converged."""
    out = levenberg_marquardt(lambda x: (x - 3.0, np.ones((1, 1))), np.array([0]), max_iter=0)
    assert (out.iterations, out.converged, out.cost) == (0, False, 4.5)
    assert out.x.dtype == float and out.x.tolist() == [0.0]


def counting_analyses(monkeypatch) -> list[int]:
    """``SparseFactor._new`` (one symbolic analysis of a new pattern) counted: the list's one item."""
    count, new = [0], SparseFactor._new

    def counted(factor, upper):
        count[0] += 1
        return new(factor, upper)

    monkeypatch.setattr(SparseFactor, "_new", counted)
    return count


@pytest.mark.parametrize("backend", BACKENDS)
def test_levenberg_marquardt_analyses_the_sparse_pattern_once(monkeypatch, backend):
    """100 unknowns (sparse path), residuals x_k^2 - (k + 1) and 0.1 (x_(k+1) - x_k): the pattern of
    J^T J + mu D never changes, so every iteration reuses one symbolic analysis. Minimiser near
    x_k = sqrt(k + 1) (the coupling shifts it slightly), reached in several iterations."""
    analyses = counting_analyses(monkeypatch)
    if backend == "qdldl":
        monkeypatch.setattr(sparse_lm, "cholmod_module", lambda: None)
    n = 100
    target = np.arange(1.0, n + 1)

    def residuals(x):
        r = np.concatenate([x * x - target, 0.1 * np.diff(x)])
        rows = np.concatenate([np.arange(n), n + np.arange(n - 1), n + np.arange(n - 1)])
        cols = np.concatenate([np.arange(n), np.arange(1, n), np.arange(n - 1)])
        vals = np.concatenate([2 * x, np.full(n - 1, 0.1), np.full(n - 1, -0.1)])
        return r, sp.csr_matrix((vals, (rows, cols)), shape=(2 * n - 1, n))

    out = levenberg_marquardt(residuals, np.full(n, 3.0))
    assert out.converged and out.iterations >= 3
    np.testing.assert_allclose(out.x, np.sqrt(target), rtol=0.02)
    assert analyses == [1]


def test_start_at_a_zero_cost_minimum_converges_at_once():
    """r(x) = x - 2 from x = 2: the step is 0 and the cost stays 0, which is accepted (not worse):
    converged after 1 iteration at x = 2."""
    out = levenberg_marquardt(lambda x: (x - 2.0, np.ones((1, 1))), np.array([2.0]))
    assert (out.x.tolist(), out.iterations, out.converged, out.cost) == ([2.0], 1, True, 0.0)


def test_no_unknowns():
    """Every pose fixed (0 unknowns): the empty step is accepted and converges at once, the cost is the
    fixed residuals' 0.5 (1 + 4)."""
    out = levenberg_marquardt(lambda x: (np.array([1.0, 2.0]), np.zeros((2, 0))), np.zeros(0))
    assert (out.x.shape, out.iterations, out.converged, out.cost) == ((0,), 1, True, 2.5)


def test_stopping_tests_are_inclusive():
    """r = (x - 1, x + 1) from x = 0: the gradient is 0, the step exactly 0 and the cost stays 1. With
    xtol = 0 (and no gain test) the zero step still counts as small (0 <= 0); with ftol = 0 (and no step
    test) the zero gain counts as small: both converge after one iteration."""
    def problem(x):
        return np.array([x[0] - 1.0, x[0] + 1.0]), np.ones((2, 1))

    for xtol, ftol in ((0.0, -1.0), (-1.0, 0.0)):
        out = levenberg_marquardt(problem, np.array([0.0]), xtol=xtol, ftol=ftol, max_iter=5)
        assert (out.iterations, out.converged, out.cost) == (1, True, 1.0)


def test_step_test_is_relative_to_the_size_of_x():
    """xtol = 1e-10 scales with 1 + |x|. From x = 0 towards 1.5e-10 the first step (1.5e-10) exceeds
    1e-10 (1 + 0): a second iteration is needed. From x = 1 towards 1 + 1.5e-10 the same step is below
    1e-10 (1 + 1): converged after one."""
    for start, iterations in ((0.0, 2), (1.0, 1)):
        goal = start + 1.5e-10
        out = levenberg_marquardt(lambda x, goal=goal: (x - goal, np.ones((1, 1))), np.array([start]), ftol=-1.0)
        assert (out.iterations, out.converged) == (iterations, True)


def test_damping_grows_until_a_step_is_accepted_then_shrinks():
    """r = x - 100, but the cost is NaN beyond x = 1 (steps there are refused). Trial steps
    100 / (1 + mu) for mu = 1e-8, 1e-7, ..., 1e2: the first one inside is at mu = 100 (x1 = 100 / 101).
    Then mu = 10: the next trial is x1 + (100 - x1) / 11."""
    calls = []

    def residuals(x):
        calls.append(x[0])
        return (np.array([x[0] - 100.0]) if x[0] <= 1.0 else np.array([np.nan])), np.ones((1, 1))

    levenberg_marquardt(residuals, np.array([0.0]), max_iter=2)
    np.testing.assert_allclose(calls[1:12], 100 / (1 + 10.0 ** np.arange(-8, 3)), rtol=1e-12)
    x1 = 100 / 101
    assert calls[12] == pytest.approx(x1 + (100 - x1) / 11, rel=1e-12)


def exp_decay(x):
    """r(x) = exp(-x): infimum at +inf, each Gauss-Newton step dx = 1, the cost falls by e^-2 (86 %)."""
    return np.exp(-x), -np.exp(-x)[:, None]


def test_minimize_defaults_match_levenberg_marquardt():
    """``minimize`` called directly with its defaults (100 iterations, xtol 1e-10, ftol 1e-12) never stops
    early on exp(-x): 100 iterations, unconverged."""
    def evaluate(x):
        r, jac = exp_decay(x)
        return NormalEquations(0.5 * float(r @ r), jac.T @ jac, jac.T @ r)

    out = minimize(evaluate, np.array([0.0]))
    assert (out.iterations, out.converged) == (100, False)


@pytest.mark.parametrize(("xtol", "ftol"), [(10.0, 1e-12), (1e-10, 0.99)])
def test_levenberg_marquardt_passes_its_tolerances_on(xtol, ftol):
    """On exp(-x) from 0 the first step is 1 (below 10 (1 + 0)) and gains 86 % of the cost (below 99 %):
    a loose xtol or ftol stops it after one iteration, converged."""
    out = levenberg_marquardt(exp_decay, np.array([0.0]), xtol=xtol, ftol=ftol)
    assert (out.iterations, out.converged) == (1, True)


def _linear_problem(calls: list[np.ndarray]):
    """r(x) = A x - b with A = [[1, 0], [0, 2], [1, 1]], b = (1, 2, 4): the minimiser solves A^T A x = A^T b,
    A^T A = [[2, 1], [1, 5]], A^T b = (5, 8): x* = (17, 11) / 9, r(x*) = (8, 4, -8) / 9, cost* = 144 / 162 = 8 / 9.
    From x0 = 0 (cost 21 / 2) the Gauss-Newton step lands on x* in one iteration (mu = 1e-8 moves it by ~1e-8)."""
    a, b = np.array([[1.0, 0.0], [0.0, 2.0], [1.0, 1.0]]), np.array([1.0, 2.0, 4.0])

    def evaluate(x):
        calls.append(x.copy())
        r = a @ x - b
        return NormalEquations(0.5 * float(r @ r), a.T @ a, a.T @ r)

    return evaluate


def test_ptol_stops_before_a_step_that_predicts_no_gain():
    """After the first step x1 ~ x*, the next step predicts -g.dx / 2 ~ 1e-16 of the cost: with ptol the
    solver stops at x1 with 2 evaluations (x0, x1); without it it evaluates x1 + dx too, a 3rd time, and
    stops on the negligible gain. Both return x* and the cost 8/9."""
    for ptol, evaluations in ((1e-6, 2), (None, 3)):
        calls: list[np.ndarray] = []
        out = minimize(_linear_problem(calls), np.zeros(2), ptol=ptol)
        assert out.converged and len(calls) == evaluations
        np.testing.assert_allclose(out.x, [17 / 9, 11 / 9], rtol=1e-7)
        assert out.cost == pytest.approx(8 / 9, rel=1e-7)


def test_ptol_is_relative_to_the_cost_and_waits_for_negligible_damping(monkeypatch):
    """At x0 = 0 the step's predicted decrease is cost(x0) - cost* = 21/2 - 8/9 = 173/18 ~ 0.916 of the cost:
    ptol = 0.95 stops at x0 at once (1 evaluation, x = 0), ptol = 0.9 does not (2 evaluations). With
    PRED_MU_MAX below mu's floor 1e-12 the damping never counts as negligible and ptol never stops (3
    evaluations, as without it)."""
    for ptol, evaluations in ((0.95, 1), (0.9, 2)):
        calls: list[np.ndarray] = []
        out = minimize(_linear_problem(calls), np.zeros(2), ptol=ptol)
        assert len(calls) == evaluations and out.converged
    assert not np.any(minimize(_linear_problem([]), np.zeros(2), ptol=0.95).x)
    monkeypatch.setattr(sparse_lm, "PRED_MU_MAX", 1e-13)
    calls = []
    minimize(_linear_problem(calls), np.zeros(2), ptol=0.95)
    assert len(calls) == 3


def test_minimize_a_negligible_rejected_step_means_converged():
    """The rule ``step_outcome`` shared with the batch, on a cost that rises at any move from x = 0 (normal
    matrix 1, so the step is -g / (1 + mu)): a step of 1e-12 is below xtol (1 + 0) = 1e-10, so its rejection
    means x = 0 is the solution (converged, one trial). With g = -1e-3 each rejection multiplies mu by 10 from
    1e-8 until the step 1e-3 / (1 + 1e7) < 1e-10 at the 16th trial: converged at x = 0 then. With g = -10 the step
    is still 1e-9 when mu passes MU_MAX = 1e10 (19 trials): the solver gives up, not converged."""
    for gradient, want, trials in ((-1e-12, True, 1), (-1e-3, True, 16), (-10.0, False, 19)):
        calls = []

        def evaluate(x: np.ndarray, calls=calls, gradient=gradient) -> NormalEquations:
            calls.append(x.copy())
            cost = 1.0 if not np.any(x) else 2.0  # any move raises the cost
            return NormalEquations(cost, np.eye(1), np.array([gradient]))

        result = minimize(evaluate, np.zeros(1), xtol=1e-10, ftol=1e-12)
        assert result.converged is want and result.x.tolist() == [0.0]
        assert len(calls) == 1 + trials
