"""Phase 1.2: swarm-topology estimation in a local frame (Eq. 20, Appendix B, Eq. B1-B6).

1. Each observation (rho_ij, phi_ij) becomes a Cartesian offset z_ij in i's body
   frame (Eq. B1).
2. The robots' local positions x_i and orientations theta_i minimise
   Q = sum_ij lambda_ij / 2 |R(theta_i) z_ij + x_i - x_j|^2 (Eq. B2-B5), solved by
   sparse Gauss-Newton/Levenberg-Marquardt with a fixed gauge: the reference robot
   sits at the origin with heading 0. Without an initial guess the start point is the
   linear relaxation of Q in (x_i, cos theta_i, sin theta_i).
3. Every observation of robot j, transformed into the local frame (Eq. B4), forms
   j's cluster; the cluster centroid is j's topology position and the cluster spread
   its uncertainty delta_p (Eq. B6).

Decisions the paper leaves open (documented in docs/localization.md):
* Robots that observe nobody have no orientation in Q: their local heading is NaN.
* delta_p uses the sample standard deviation (ddof=1) of each cluster axis, and is
  never below half of one observation's expected spread sqrt(s_r^2 + (rho s_b)^2)
  (a cluster of one point has exactly that spread), so a robot seen once or twice
  cannot receive an unbounded weight in Eq. 22.
* A robot nobody observed (measured data; a run leaves it out first) has no cluster: its position is
  the solution of Eq. B2, fixed by what it observed, and delta_p that of one observation at the mean
  range it measured over sqrt(observations made).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import cast

import numpy as np
import scipy.sparse as sp

from coordinator.localization.sparse_lm import LsqResult, PoseLayout, jacobian, levenberg_marquardt, minimize, solve_normal
from coordinator.localization.topology_normal import TopologyNormal
from coordinator.localization.topology_terms import heading_curvature, observation_jacobian, observation_offsets, observation_residuals
from runtime.errors import LocalizationError
from runtime.models.config import ModelConfig
from runtime.models.geometry import rotate, wrap_angle

# Convergence of Eq. B3's least squares (``sparse_lm.minimize``: relative step, relative cost decrease).
# Observations are centimetre-accurate; 1e-8 stops within 1e-8 m of 1e-10 / 1e-12's answer (measured on
# random swarms of 10-500 robots) and saves about one iteration in seven, as the joint localizer's.
XTOL, FTOL = 1e-8, 1e-8
ALIGN_MIN = 2048  # robots from which a given start is first turned to the observations' headings (``aligned_start``)
LARGE_MIN = 2048  # robots from which Eq. B3's normal equations are assembled directly and one factorization serves a step


@dataclass(frozen=True)
class Topology:
    """Topology T (Eq. 14) in the local frame whose origin and x-axis are the reference robot's pose."""

    positions: np.ndarray  # (n, 2) cluster centroids, Fig. B2 yellow (m)
    solved_positions: np.ndarray  # (n, 2) minimiser of Eq. B2, Fig. B2 gray (m)
    headings: np.ndarray  # (n,) local orientations (rad), NaN for robots observing nobody
    delta_p: np.ndarray  # (n,) Eq. B6 (m)
    heading_sigma: np.ndarray  # (n,) approx. s_b / sqrt(#observations made) (rad), inf if none
    reference: int  # index of the gauge robot


def _relaxed_start(n: int, i: np.ndarray, j: np.ndarray, z: np.ndarray, has_heading: np.ndarray, ref: int) -> np.ndarray:
    """Poses from the linear relaxation of Eq. B3 in (x, y, c, s) with the gauge fixed.

    Replacing (cos theta_i, sin theta_i) by free (c_i, s_i) makes Q quadratic; the
    reference robot's (x, y, c, s) = (0, 0, 1, 0). A tiny ridge keeps the system
    solvable where the relaxation has more freedom than the original problem.
    """
    free = np.arange(n) != ref
    present = np.stack([free, free, free & has_heading, free & has_heading], axis=1)
    cols = np.where(present, np.cumsum(present.ravel()).reshape(n, 4) - 1, -1)
    n_cols = int(present.sum())
    m = len(i)
    rx, ry = 2 * np.arange(m), 2 * np.arange(m) + 1
    zx, zy, ones = z[:, 0], z[:, 1], np.ones(m)
    ci, cj = cols[i], cols[j]
    rows = np.concatenate([rx, rx, rx, rx, ry, ry, ry, ry])
    col = np.concatenate([ci[:, 2], ci[:, 3], ci[:, 0], cj[:, 0], ci[:, 3], ci[:, 2], ci[:, 1], cj[:, 1]])
    vals = np.concatenate([zx, -zy, ones, -ones, zx, zy, ones, -ones])
    a = jacobian(2 * m, n_cols, rows, col, vals)
    at_ref = i == ref  # the reference's known (c, s) = (1, 0) go to the right-hand side
    b = np.zeros(2 * m)
    b[rx[at_ref]] = -zx[at_ref]
    b[ry[at_ref]] = -zy[at_ref]
    ata = a.T @ a
    ridge = 1e-9 * max(float(ata.diagonal().max(initial=1.0)), 1.0)
    ridged = ata + ridge * np.eye(n_cols) if isinstance(ata, np.ndarray) else ata.tocsr() + sp.identity(n_cols) * ridge
    sol = solve_normal(ridged, a.T @ b)
    full = np.zeros((n, 4))
    full[:, 2] = 1.0
    full[present] = sol[cols[present]]
    return np.stack([full[:, 0], full[:, 1], np.arctan2(full[:, 3], full[:, 2])], axis=1)


def _to_reference_frame(poses: np.ndarray, ref: int) -> np.ndarray:
    """Express poses in the frame of robot ``ref`` (its pose becomes (0, 0, 0))."""
    return to_reference_frame(poses, poses[ref])


def to_reference_frame(poses: np.ndarray, ref_pose: np.ndarray) -> np.ndarray:
    """Poses (..., n, 3) expressed in the frame whose pose is ``ref_pose`` (..., 3), batched."""
    out = np.empty_like(poses)
    out[..., :2] = rotate(-ref_pose[..., None, 2], poses[..., :2] - ref_pose[..., None, :2])
    out[..., 2] = wrap_angle(poses[..., 2] - ref_pose[..., None, 2])
    return out


def aligned_start(start: np.ndarray, observer: np.ndarray, observed: np.ndarray, bearing_rad: np.ndarray, ref: int) -> np.ndarray:
    """``start`` (n, 3, in the reference robot's frame) with each observer's heading turned by the circular mean of
    its bearings' misfit (the direction to each robot it saw, from the start's positions, less heading + bearing),
    and everything turned about the reference so that its heading stays 0.

    A large swarm's start (dead reckoning) sits in the frame of the reference robot's dead-reckoned heading; its
    error turns the whole swarm about the reference, centimetres to decimetres at metres away, which
    Levenberg-Marquardt took 8 (3000 robots) to 14 (10,000) iterations to undo. Only from ``ALIGN_MIN`` robots:
    the solution is the same to the tolerance (``XTOL``), not to the bit, and smaller runs keep theirs."""
    turn = heading_turn(start, observer, observed, bearing_rad)
    out = np.empty_like(start)
    out[:, :2] = rotate(-turn[ref], start[:, :2] - start[ref, :2]) + start[ref, :2]
    out[:, 2] = wrap_angle(start[:, 2] + turn - turn[ref])
    return out


def heading_turn(poses: np.ndarray, observer: np.ndarray, observed: np.ndarray, bearing_rad: np.ndarray,
                 range_m: np.ndarray | None = None) -> np.ndarray:
    """Each observer's turn (n,): the circular mean of its bearings' misfit, the direction to each robot it saw (from
    ``poses`` (n, 3)) less its heading and the bearing; 0 for a robot that saw nobody. With ``range_m`` each misfit
    is weighted by the observed range times the distance between the two positions: the minimiser of Eq. B3 over the
    observer's heading alone, every position held."""
    d = poses[observed, :2] - poses[observer, :2]
    misfit = np.arctan2(d[:, 1], d[:, 0]) - poses[observer, 2] - bearing_rad
    n = len(poses)
    if range_m is None:
        return np.arctan2(np.bincount(observer, np.sin(misfit), n), np.bincount(observer, np.cos(misfit), n))
    w = range_m * np.hypot(d[:, 0], d[:, 1])
    return np.arctan2(np.bincount(observer, w * np.sin(misfit), n), np.bincount(observer, w * np.cos(misfit), n))


def reference_robot(made: np.ndarray) -> np.ndarray:
    """The gauge: index of the lowest-indexed robot that observed someone (``made`` (..., n) observations made)."""
    return cast(np.ndarray, np.argmax(made > 0, axis=-1))


def cluster_delta_p(
    count: np.ndarray, centroid: np.ndarray, sq: np.ndarray, mean_range: np.ndarray, cfg: ModelConfig
) -> np.ndarray:
    """Eq. B6 with the floors of the module docstring, from each cluster's moments (batched over leading axes).

    ``count`` (..., n) points per cluster, ``centroid`` (..., n, 2), ``sq`` (..., n, 2) sums of squared
    coordinates, ``mean_range`` (..., n) mean observed range of the cluster's observations.
    """
    var = np.maximum(sq - count[..., None] * centroid**2, 0.0) / np.maximum(count - 1.0, 1.0)[..., None]
    single = np.sqrt(cfg.range_sigma_m**2 + (mean_range * cfg.bearing_sigma_rad) ** 2)
    b6 = np.sqrt(var.sum(axis=-1))  # Eq. B6
    return np.where(count >= 2, np.maximum(b6, 0.5 * single), single)


def heading_sigmas(made: np.ndarray, cfg: ModelConfig) -> np.ndarray:
    """Topology heading std s_b / sqrt(observations made) (rad), inf for robots that observed nobody."""
    return np.where(made > 0, cfg.bearing_sigma_rad / np.sqrt(np.maximum(made, 1)), np.inf)


def solve_by_jacobian(layout: PoseLayout, start: np.ndarray, observer: np.ndarray, observed: np.ndarray, z: np.ndarray,
                      huber: float | None) -> LsqResult:
    """Eq. B3 by ``levenberg_marquardt`` on its residuals and sparse Jacobian, with the heading curvature."""
    m = len(observer)
    rows_x, rows_y = 2 * np.arange(m), 2 * np.arange(m) + 1
    ci, cj = layout.cols[observer], layout.cols[observed]

    zx, zy = z[:, 0], z[:, 1]
    ones = np.ones(m)
    rows = np.concatenate([rows_x, rows_x, rows_x, rows_y, rows_y, rows_y])
    cols = np.concatenate([ci[:, 0], cj[:, 0], ci[:, 2], ci[:, 1], cj[:, 1], ci[:, 2]])
    last: dict[str, np.ndarray] = {}  # R(theta_i) z_ij at the last point ``residuals`` saw, for ``second_order``

    def residuals(vec: np.ndarray) -> tuple[np.ndarray, sp.csr_matrix]:
        poses = layout.unpack(vec, start)
        heading = poses[observer, 2]
        pi, pj = poses[observer], poses[observed]
        rz, r = np.empty((m, 2)), np.empty((m, 2))
        observation_residuals(np.cos(heading), np.sin(heading), zx, zy, pi[:, 0], pi[:, 1], pj[:, 0], pj[:, 1],
                              out=(rz[:, 0], rz[:, 1], r[:, 0], r[:, 1]))
        last["vec"], last["rz"] = vec, rz
        d_theta = observation_jacobian(rz[:, 0], rz[:, 1])
        vals = np.concatenate([ones, -ones, d_theta[0], ones, -ones, d_theta[1]])
        return r.ravel(), jacobian(2 * m, layout.size, rows, cols, vals)

    def second_order(vec: np.ndarray, r: np.ndarray) -> np.ndarray:
        """d^2 r / d theta_i^2 = -R(theta_i) z_ij: diagonal of sum r . d^2 r on heading columns."""
        if last.get("vec") is not vec:
            residuals(vec)
        r2, rz = r.reshape(m, 2), last["rz"]
        term = heading_curvature(rz[:, 0], rz[:, 1], r2[:, 0], r2[:, 1])
        out = np.zeros(layout.size)
        hc = ci[:, 2]
        np.add.at(out, hc[hc >= 0], term[hc >= 0])
        return out

    return levenberg_marquardt(residuals, layout.pack(start), second_order=second_order, huber=huber, xtol=XTOL, ftol=FTOL)


def estimate_topology(
    n: int,
    observer: np.ndarray,
    observed: np.ndarray,
    range_m: np.ndarray,
    bearing_rad: np.ndarray,
    cfg: ModelConfig,
    *,
    initial_poses: np.ndarray | None = None,
    huber: float | None = None,
) -> Topology:
    """Estimate the topology of ``n`` robots from observations given as robot indices.

    ``initial_poses`` (n, 3), e.g. dead reckoning, only seeds the solver; the result is
    expressed in the reference robot's frame either way. ``huber`` (metres) switches the
    loss of Eq. B3 to Huber beyond that residual (per axis) to resist outliers in real data,
    and leaves observations more than 2 x ``huber`` from the solution out of the clusters.
    Callers check observability first (``graph.require_observable``).
    """
    has_heading = np.bincount(observer, minlength=n) > 0
    ref = int(reference_robot(has_heading))
    z = observation_offsets(range_m, bearing_rad)
    start = _relaxed_start(n, observer, observed, z, has_heading, ref) if initial_poses is None else initial_poses
    start = _to_reference_frame(np.asarray(start, float), ref)
    if initial_poses is not None and n >= ALIGN_MIN:
        start = aligned_start(start, observer, observed, bearing_rad, ref)
    start[~has_heading, 2] = 0.0
    free = np.arange(n) != ref
    layout = PoseLayout(free, free & has_heading)
    if n >= LARGE_MIN:  # the normal equations summed directly, one factorization a step (``topology_normal``)
        problem = TopologyNormal(layout.cols, layout.size, start, observer, observed, z, huber)
        result = minimize(problem.evaluate, layout.pack(start), solve=problem.solve, xtol=XTOL, ftol=FTOL)
    else:
        result = solve_by_jacobian(layout, start, observer, observed, z, huber)
    if not result.converged:
        raise LocalizationError("no-convergence", [], "topology least squares did not converge")
    poses = layout.unpack(result.x, start)
    poses[:, 2] = wrap_angle(poses[:, 2])
    centroid, delta_p, heading_sigma = clusters(poses, observer, observed, z, range_m, cfg, huber)
    headings = np.where(has_heading, poses[:, 2], np.nan)
    return Topology(centroid, poses[:, :2].copy(), headings, delta_p, heading_sigma, ref)


def clusters(poses: np.ndarray, observer: np.ndarray, observed: np.ndarray, z: np.ndarray, range_m: np.ndarray,
             cfg: ModelConfig, huber: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Eq. B4-B6 from the solved ``poses`` (n, 3) of Eq. B3: every observation, transformed by its observer's pose, is
    a point of the observed robot's cluster (the module docstring). Returns the topology positions (n, 2), delta_p
    (n,) and the heading sigmas (n,), as ``Topology``'s."""
    n, m = len(poses), len(observer)
    # Eq. B4 for every observation: cluster points of the observed robots (Fig. B2 blue).
    points = rotate(poses[observer, 2], z) + poses[observer, :2]
    use = np.ones(m)
    if huber is not None:  # robust mode: gross outliers leave the clusters (unless a robot has no other point)
        inlier = np.hypot(*(points - poses[observed, :2]).T) <= 2.0 * huber
        use = np.where(inlier | (np.bincount(observed, inlier, n)[observed] == 0), 1.0, 0.0)
    count = np.bincount(observed, use, n)
    safe = np.maximum(count, 1.0)
    centroid = np.stack([np.bincount(observed, use * points[:, k], n) for k in range(2)], axis=1) / safe[:, None]
    sq = np.stack([np.bincount(observed, use * points[:, k] ** 2, n) for k in range(2)], axis=1)
    mean_range = np.bincount(observed, use * range_m, n) / safe
    made = np.bincount(observer, minlength=n)
    unseen = count == 0  # measured data: a robot nobody saw, fixed by what it saw
    if unseen.any():
        mean_range = np.where(unseen, np.bincount(observer, range_m, n) / np.maximum(made, 1), mean_range)
    delta_p = cluster_delta_p(count, centroid, sq, mean_range, cfg) / np.sqrt(np.where(unseen, np.maximum(made, 1), 1))
    centroid = np.where(count[:, None] > 0, centroid, poses[:, :2])
    return centroid, delta_p, heading_sigmas(made, cfg)
