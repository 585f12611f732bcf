"""A large swarm's topology (``topology_normal``): Eq. B3's normal equations summed straight into their pattern equal
J^T J of the sparse Jacobian, the preconditioned solves equal direct ones, and the solution is the Jacobian path's."""

from typing import Any, cast

import numpy as np
import pytest
import scipy.sparse as sp

import coordinator.localization.topology as topology
import coordinator.localization.topology_normal as topology_normal
from coordinator.localization.sparse_lm import PoseLayout, huber_weights, jacobian
from runtime.models.config import ModelConfig
from runtime.models.geometry import rotate, wrap_angle
from runtime.models.rng import Stream, robot_rngs
from runtime.models.sensing import sense_swarm
from runtime.models.trajectory import body_spacing, random_trajectory

CFG = ModelConfig()


def swarm(n: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(truth (n, 3) with headings near +-pi, observer, observed, range, bearing) of a random swarm; robot 3 observes
    nobody."""
    rng = np.random.default_rng(seed)
    truth = random_trajectory(n, 1, rng, sensing_range=CFG.sensing_range_m, **body_spacing(CFG)).initial_poses.copy()
    truth[:, 2] = rng.choice([-np.pi, np.pi - 1e-9, 0.5], n) + rng.normal(0.0, 0.01, n)
    ids = np.arange(n)
    obs = sense_swarm(truth, ids, CFG, robot_rngs(seed, ids, Stream.SENSING))
    i, j = obs.indexed(ids)
    keep = i != 3
    return truth, i[keep], j[keep], obs.range_m[keep], obs.bearing_rad[keep]


def problem(n: int, seed: int, huber: float | None, off: float) -> tuple[topology_normal.TopologyNormal, PoseLayout, np.ndarray,
                                                                        tuple[np.ndarray, ...]]:
    """The normal equations of a random swarm at a start ``off`` (m, rad) off the truth, its layout, start and data."""
    truth, i, j, range_m, bearing = swarm(n, seed)
    has = np.bincount(i, minlength=n) > 0
    ref = int(topology.reference_robot(has))
    free = np.arange(n) != ref
    layout = PoseLayout(free, free & has)
    start = truth + np.random.default_rng(seed + 1).normal(0.0, off, truth.shape)
    start[~has, 2] = 0.0
    z = topology.observation_offsets(range_m, bearing)
    return topology_normal.TopologyNormal(layout.cols, layout.size, start, i, j, z, huber), layout, start, (i, j, z)


def jacobian_system(layout: PoseLayout, start: np.ndarray, i: np.ndarray, j: np.ndarray, z: np.ndarray,
                    huber: float | None) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    """(cost, J^T W J, J^T W r, curvature) from the sparse Jacobian, as ``levenberg_marquardt`` forms them."""
    poses = start.copy()
    m = len(i)
    rz = rotate(poses[i, 2], z)
    r = (rz + poses[i, :2] - poses[j, :2]).ravel()
    ci, cj = layout.cols[i], layout.cols[j]
    rows = np.concatenate([2 * np.arange(m)] * 3 + [2 * np.arange(m) + 1] * 3)
    cols = np.concatenate([ci[:, 0], cj[:, 0], ci[:, 2], ci[:, 1], cj[:, 1], ci[:, 2]])
    vals = np.concatenate([np.ones(m), -np.ones(m), -rz[:, 1], np.ones(m), -np.ones(m), rz[:, 0]])
    jac = np.asarray(sp.csr_matrix(jacobian(2 * m, layout.size, rows, cols, vals)).toarray())
    w, cost = huber_weights(r, huber)
    sw = np.ones(2 * m) if w is None else np.sqrt(w)
    jw, rw = sw[:, None] * jac, sw * r
    curvature = np.zeros(layout.size)
    heading = ci[:, 2] >= 0
    np.add.at(curvature, ci[heading, 2], topology.heading_curvature(rz[:, 0], rz[:, 1], rw[0::2], rw[1::2])[heading])
    return cost, jw.T @ jw, jw.T @ rw, curvature


@pytest.mark.parametrize("huber", [None, 0.02])
def test_normal_equations_are_the_jacobians(huber: float | None) -> None:
    normal, layout, start, (i, j, z) = problem(40, 2, huber, 0.05)
    ne = normal.evaluate(layout.pack(start))
    lower = cast(sp.csr_matrix, ne.normal)
    cost, a, g, curvature = jacobian_system(layout, start, i, j, z, huber)
    assert ne.cost == pytest.approx(cost, rel=1e-12)
    np.testing.assert_allclose(lower.toarray(), np.tril(a), rtol=0, atol=1e-12 * np.abs(a).max())  # the lower triangle
    np.testing.assert_allclose(ne.gradient, g, rtol=0, atol=1e-12 * np.abs(g).max())
    np.testing.assert_allclose(cast(np.ndarray, ne.curvature), curvature, rtol=0, atol=1e-12 * np.abs(curvature).max())


def test_solves_factorized_preconditioned_and_refactorized(monkeypatch: pytest.MonkeyPatch) -> None:
    normal, layout, start, _ = problem(60, 4, None, 0.002)  # near the minimum, as the later systems of a step are
    ne = normal.evaluate(layout.pack(start))
    lower, rhs = cast(sp.csr_matrix, ne.normal), -ne.gradient
    a = lower.toarray() + np.tril(lower.toarray(), -1).T
    shift = 1e-8 * np.diag(a)
    curved = np.maximum(cast(np.ndarray, ne.curvature), -0.9 * np.diag(a))
    factorized: list[bool] = []
    factorize = normal._factor.solve_upper

    def counted(*args: Any, **kwargs: Any) -> np.ndarray:
        factorized.append(True)
        return factorize(*args, **kwargs)

    monkeypatch.setattr(normal._factor, "solve_upper", counted)
    first = normal.solve(lower, shift, rhs)  # factorized
    np.testing.assert_allclose(first, np.linalg.solve(a + np.diag(shift), rhs), rtol=1e-9, atol=1e-12)
    exact = np.linalg.solve(a + np.diag(curved + shift), rhs)
    second = normal.solve(lower + sp.diags(curved), shift, rhs)  # conjugate gradients on the first factor
    assert len(factorized) == 1
    assert np.abs(second - exact).max() <= 1e-5 * np.abs(exact).max()
    monkeypatch.setattr(topology_normal, "PCG_MAX_ITER", 0)  # they give up: factorized afresh
    third = normal.solve(lower + sp.diags(curved), shift, rhs)
    assert len(factorized) == 2
    np.testing.assert_allclose(third, exact, rtol=1e-9, atol=1e-12 * np.abs(exact).max())
    dropped = lower.copy()  # an entry summed to exactly zero leaves the pattern: the general solve
    dropped.data[np.flatnonzero(dropped.indices != np.repeat(np.arange(len(a)), np.diff(dropped.indptr)))[0]] = 0.0
    dropped.eliminate_zeros()
    full = dropped.toarray() + np.tril(dropped.toarray(), -1).T
    np.testing.assert_allclose(normal.solve(dropped, shift, rhs), np.linalg.solve(full + np.diag(shift), rhs), rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("huber", [None, 0.05])
def test_large_path_finds_the_jacobian_paths_topology(monkeypatch: pytest.MonkeyPatch, huber: float | None) -> None:
    truth, i, j, range_m, bearing = swarm(300, 1)
    start = truth + np.random.default_rng(5).normal(0.0, 0.02, truth.shape)

    def solve(large_min: int) -> topology.Topology:
        monkeypatch.setattr(topology, "LARGE_MIN", large_min)
        return topology.estimate_topology(300, i, j, range_m, bearing, CFG, initial_poses=start, huber=huber)

    plain, large = solve(10**9), solve(0)
    assert large.reference == plain.reference
    assert np.max(np.abs(large.solved_positions - plain.solved_positions)) < 1e-8  # the same minimum (m)
    assert np.max(np.abs(large.positions - plain.positions)) < 1e-8
    both = np.isfinite(plain.headings)
    assert np.array_equal(both, np.isfinite(large.headings))
    assert np.max(np.abs(wrap_angle(large.headings[both] - plain.headings[both]))) < 1e-8
    np.testing.assert_allclose(large.delta_p, plain.delta_p, rtol=1e-6)
