"""Batched localization of many small swarms at once (the Monte Carlo planner of Eq. 8).

The planner localizes B = (candidate plans x Monte Carlo samples) swarms per step. This
module solves all of them together with numpy over a leading batch axis, with the same
model, maths and decisions as the single-swarm localizers (``PaperLocalizer``, ``JointLocalizer``):

* observations are dense (B, n, n) arrays: ``seen[b, i, j]`` means robot i observed robot j
  in sample b, with ``ranges``/``bearings`` holding the measurement (ignored elsewhere);
* the residuals and Jacobians are the single-swarm problems' own functions, elementwise on those
  dense pair arrays (``range_bearing.observation_residuals``/``observation_jacobian``,
  ``topology_terms.observation_residuals``/``observation_jacobian``/``heading_curvature``, the prior's
  ``pose_difference``/``prior_information``); only the assembly differs: the normal matrix J^T J is
  formed from the per-pair blocks directly (no (B, 2 n^2, 3 n) Jacobian);
* headings couple only with positions in J^T J (their block is diagonal), so each Newton
  step eliminates them (Schur complement) and solves a (B, 2n, 2n) stack with
  ``np.linalg.solve``;
* the solver is ``sparse_lm.drive``, the Levenberg-Marquardt driver of the single-swarm localizers, with
  ``BatchOps``: every sample runs in lock-step until it has converged or failed, finished samples leave
  the work set, and each takes the steps the single-swarm solver takes: the results agree to rounding
  (poses ~1e-12 m, covariances ~1e-12 relative; ~5e-9 relative on exact priors, whose 1e12 information
  leaves the inverse at rounding);
* the joint localizer's observability constraint (``gauge``, on by default) is applied as in the runtime:
  the same correction (``gauge.gauge_correction``) enters the inverse of J^T J through the Woodbury
  identity, the estimate takes ``constrained_solution``'s step and the covariances are transported
  (``gauge.transported_blocks``), without forming any (3n, 3n) matrix;
* the batch is processed in chunks of about ``CHUNK_PAIRS`` pair entries with reused work
  arrays: large fresh numpy temporaries cost page faults on every Newton iteration.

Pose unknowns the sparse code holds fixed (the reference robot of the paper's gauge, the
heading of a robot that observed nobody) keep their column with an identity row, so
they do not move and the other unknowns solve exactly the reduced system.

A sample that cannot be fully localized (a robot nobody observed, a disconnected observation
graph, a degenerate topology, no convergence) gets ``ok = False`` and the runtime's answer
(``partial.localize_observable``): the largest observable group is localized, the other
robots keep dead reckoning. For the joint method that is the batched solve with the other
robots' observations removed (a robot without observations keeps its prior exactly; the gauge is
the localized robots', as in ``JointLocalizer.localize_subset``); samples that still fail, and the
paper's method, go through the single-swarm runtime code.
Samples holding invalid values get ``ok = False`` and dead reckoning; no exception is raised.

The batch is given the localizer object itself (the executor's, with its options). The built-in
localizers without a Huber loss are solved here, vectorised; any other localizer (a registered
one, or a built-in with ``huber`` set) localizes every sample through the localizer itself
(``partial.localize_observable``, as the runtime), one sample at a time.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Self, TypeAlias, cast

import numpy as np

from coordinator.localization import Localizer
from coordinator.localization.allocator import retain_freed_memory
from coordinator.localization.dead_reckoning import dead_reckon_arrays, exact_moments
from coordinator.localization.gauge import (
    constrained_covariance,
    constrained_solution,
    gauge_correction,
    gauge_frame,
    gauge_gradient,
    transport,
    transport_offset,
    transported_blocks,
)
from coordinator.localization.graph import observable_subset
from coordinator.localization.joint import EXACT_COV_LIMIT, FTOL, PTOL, XTOL, JointLocalizer, block_diagonal, implausible, psd, rescue_start
from coordinator.localization.paper import PaperLocalizer, fuse
from coordinator.localization.partial import localize_observable
from coordinator.localization.range_bearing import (
    bearing_weights,
    observation_jacobian,
    observation_residuals,
    pose_difference,
    prior_information,
    sensor_sigmas,
)
from coordinator.localization.sparse_lm import BatchOps, blas_threads, clamp_curvature, damping_scale, drive
from coordinator.localization.superimpose import MIN_SPREAD, fusion_weights, weighted_procrustes
from coordinator.localization.topology import (
    FTOL as TOPOLOGY_FTOL,
    XTOL as TOPOLOGY_XTOL,
    cluster_delta_p,
    heading_sigmas,
    reference_robot,
    to_reference_frame,
)
from coordinator.localization.topology_terms import (
    heading_curvature,
    observation_jacobian as topology_jacobian,
    observation_offsets,
    observation_residuals as topology_residuals,
)
from runtime.errors import SwarmInputError
from runtime.models.config import ModelConfig
from runtime.models.geometry import wrap_angle
from runtime.models.state import Observations, StepCommands, SwarmEstimate

# (xtol, ftol, ptol): sparse_lm's convergence test, so every sample takes the steps the single-swarm solver takes.
# Where convergence is linear (Gauss-Newton of the joint problem; weakly constrained headings in the
# topology) this stops up to ~3e-8 (joint) / ~6e-8 (paper) short of the exact minimum; a tighter tolerance
# would be more accurate than the single-swarm localizers but then no longer agree with them to 1e-8.
PAPER_TOL = (TOPOLOGY_XTOL, TOPOLOGY_FTOL, None)  # the paper localizer's topology solve's
JOINT_TOL = (XTOL, FTOL, PTOL)  # the single-swarm joint localizer's (joint.XTOL, FTOL, PTOL)
CHUNK_PAIRS = 40_000  # samples x n^2 solved together (about 400 swarms of 10 robots, 4 of 100)
MIN_CHUNK = 4  # samples
# Above this condition number of the Woodbury identity's 6x6 system (I + K U^T L) the observability-constrained update
# is done densely, as the single-swarm localizer does it (measured: up to 1.5e7 at the default noise, 4e9 at a quarter
# of its sensing noise; 7e28 with noise-free sensing and a prior that disagrees with it, where the identity gave 3e7 m)
WOODBURY_COND_LIMIT = 1e11

_EYE6 = np.eye(6)
_Solved: TypeAlias = tuple[np.ndarray, np.ndarray, np.ndarray]  # poses (B, n, 3), covariances (B, n, 3, 3), ok (B,)


@dataclass(frozen=True)
class BatchEstimate:
    """Post-step estimates of B swarms of n robots."""

    poses: np.ndarray  # (B, n, 3)
    cov: np.ndarray  # (B, n, 3, 3)
    ok: np.ndarray  # (B,) bool: False where the sample could not be localized (poses/cov = dead reckoning)


def batched_method(localizer: Localizer) -> str | None:
    """``paper`` or ``joint`` where this module solves ``localizer``'s problem vectorised, else None
    (every sample then goes through the localizer itself)."""
    kind = type(localizer)
    if kind in (PaperLocalizer, JointLocalizer) and getattr(localizer, "huber", None) is None:
        return localizer.name
    return None


def localize_batch(
    localizer: Localizer,
    cfg: ModelConfig,
    prior_poses: np.ndarray,
    prior_cov: np.ndarray,
    commands: np.ndarray,
    moving: np.ndarray,
    seen: np.ndarray,
    ranges: np.ndarray,
    bearings: np.ndarray,
    covariances: bool = True,
) -> BatchEstimate:
    """Localize B swarms: ``localizer.localize`` applied to every sample.

    ``prior_poses`` (B, n, 3), ``prior_cov`` (B, n, 3, 3), ``commands`` (B, n, 2) body-frame
    (turn rad, drive m; ignored where not ``moving``), ``moving`` (B, n), ``seen`` (B, n, n) with
    ``seen[b, i, j]`` = robot i observed robot j (the diagonal is ignored), ``ranges``/``bearings``
    (B, n, n) (m, rad; only read where ``seen``). Where a sample could not be fully localized
    (unobservable, degenerate, no convergence) ``ok`` is False and its poses/covariances are
    the runtime's partial localization (``partial.localize_observable``); where it holds
    values the single-swarm input types reject, ``ok`` is False and they are dead reckoning.

    ``covariances=False``: the caller reads only poses and ``ok`` (the Monte Carlo's last step of a plan); the joint
    method then skips the covariances of its update (the same flags; the same poses to rounding: the constrained
    update solves for them instead of inverting) and ``cov`` holds NaN where it solved a sample.
    """
    retain_freed_memory()  # thousands of 0.1-1 MB arrays a selection: no page faults on each (``allocator``)
    prior_poses = np.asarray(prior_poses, dtype=float)
    if prior_poses.ndim != 3 or prior_poses.shape[2] != 3:
        raise SwarmInputError(f"prior_poses must have shape (B, n, 3), got {prior_poses.shape}")
    b, n = prior_poses.shape[:2]
    prior_cov = _shaped(prior_cov, (b, n, 3, 3), "prior_cov", float)
    commands = _shaped(commands, (b, n, 2), "commands", float)
    moving = _shaped(moving, (b, n), "moving", bool)
    seen = _shaped(seen, (b, n, n), "seen", bool) & _off_diagonal(n)
    ranges = _shaped(ranges, (b, n, n), "ranges", float)
    bearings = _shaped(bearings, (b, n, n), "bearings", float)

    dr_poses, dr_cov = dead_reckon_arrays(prior_poses, prior_cov, commands, moving, cfg, exact_moments(localizer))
    if n == 0:
        return BatchEstimate(dr_poses, dr_cov, np.ones(b, bool))
    valid = _valid(prior_poses, prior_cov, commands, moving, seen, ranges, bearings)
    poses, cov = dr_poses.copy(), dr_cov.copy()
    method = batched_method(localizer)
    if method is None:
        ok = _localize_each(localizer, cfg, np.flatnonzero(valid), prior_poses, prior_cov, commands, moving, seen, ranges,
                            bearings, poses, cov)
        return BatchEstimate(poses, cov, valid & ok)
    ok = valid & observable(seen)
    solve: _Solver = (_localize_paper if method == "paper"
                      else functools.partial(_localize_joint, constrain=_constrained(localizer, n), covariances=covariances))
    todo = np.flatnonzero(ok)
    chunk = max(MIN_CHUNK, CHUNK_PAIRS // (n * n))
    ws = _Workspace()  # shared by the chunks
    with blas_threads(3 * n * min(todo.size, chunk)):  # many small solves: one BLAS thread is fastest
        _solve_chunks(solve, cfg, todo, chunk, dr_poses, dr_cov, seen, ranges, bearings, poses, cov, ok, ws)
        partial = np.flatnonzero(valid & ~ok)
        if partial.size:
            _localize_partial(localizer, method, cfg, partial, prior_poses, prior_cov, commands, moving, seen, ranges, bearings, poses, cov, ws,
                              covariances)
    return BatchEstimate(poses, cov, ok)


def _solve_chunks(solve: _Solver, cfg: ModelConfig, todo: np.ndarray, chunk: int, dr_poses: np.ndarray, dr_cov: np.ndarray,
                  seen: np.ndarray, ranges: np.ndarray, bearings: np.ndarray, poses: np.ndarray, cov: np.ndarray, ok: np.ndarray,
                  ws: _Workspace) -> None:
    """Localize samples ``todo`` chunk by chunk into poses/cov; samples that fail get ok = False."""
    for start in range(0, todo.size, chunk):  # chunks keep the working arrays small (cache, allocator)
        sel = todo[start : start + chunk]
        est, est_cov, good = solve(cfg, dr_poses[sel], dr_cov[sel], seen[sel], ranges[sel], bearings[sel], ws)
        poses[sel[good]] = est[good]
        cov[sel[good]] = est_cov[good]
        ok[sel[~good]] = False


def _constrained(localizer: Localizer, n: int) -> bool:
    """Whether the joint localizer's update of n robots is observability-constrained (``JointLocalizer._solve``)."""
    return isinstance(localizer, JointLocalizer) and localizer.constrain_gauge and n <= EXACT_COV_LIMIT


def _localize_partial(localizer: Localizer, method: str, cfg: ModelConfig, index: np.ndarray, prior_poses: np.ndarray,
                      prior_cov: np.ndarray, commands: np.ndarray, moving: np.ndarray, seen: np.ndarray, ranges: np.ndarray,
                      bearings: np.ndarray, poses: np.ndarray, cov: np.ndarray, ws: _Workspace, covariances: bool = True) -> None:
    """The runtime's partial localization (``partial.localize_observable``) of samples ``index``, into poses/cov
    (``covariances=False``: the batched joint solve's covariances are NaN, as ``localize_batch``'s)."""
    n = seen.shape[1]
    rest = index
    if method == "joint":
        masked = seen[index].copy()
        for k, b in enumerate(index):
            i, j = np.nonzero(seen[b])
            keep, _ = observable_subset(np.arange(n), i, j)
            masked[k] &= keep[:, None] & keep[None, :] if keep.sum() >= 2 else False
        dr_poses, dr_cov = poses[index], cov[index]  # dead reckoning at this point
        keep = masked.any(axis=1) | masked.any(axis=2)  # the robots localized (the others keep their dead reckoning)
        est, est_cov, good = _localize_joint(cfg, dr_poses, dr_cov, masked, ranges[index], bearings[index], ws, _constrained(localizer, n), keep,
                                             covariances)
        poses[index[good]], cov[index[good]] = est[good], est_cov[good]
        rest = index[~good]
    _localize_each(localizer, cfg, rest, prior_poses, prior_cov, commands, moving, seen, ranges, bearings, poses, cov)


def _localize_each(localizer: Localizer, cfg: ModelConfig, index: np.ndarray, prior_poses: np.ndarray, prior_cov: np.ndarray,
                   commands: np.ndarray, moving: np.ndarray, seen: np.ndarray, ranges: np.ndarray, bearings: np.ndarray,
                   poses: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """The runtime's localization (``partial.localize_observable``) of samples ``index`` one by one, into poses/cov.

    Returns (B,) True where no robot of the sample was left at dead reckoning.
    """
    ids = np.arange(seen.shape[1])
    whole = np.zeros(len(seen), bool)
    for b in index:
        i, j = np.nonzero(seen[b])
        est, excluded = localize_observable(
            localizer, SwarmEstimate(ids, prior_poses[b], prior_cov[b]), StepCommands(ids, commands[b], moving[b]),
            Observations(i, j, ranges[b, i, j], bearings[b, i, j]), cfg,
        )
        poses[b], cov[b] = est.poses, est.cov
        whole[b] = not excluded
    return whole


def observable(seen: np.ndarray) -> np.ndarray:
    """(B,) True where every robot was observed by another and the undirected observation graph is connected."""
    b, n, _ = seen.shape
    observed: np.ndarray = np.all(np.any(seen, axis=1), axis=1)
    both = (seen | seen.swapaxes(1, 2)).astype(float)
    reach = np.zeros((b, 1, n))
    reach[:, 0, 0] = 1.0
    for _ in range(n):  # breadth-first search from robot 0 in every sample at once
        grown = ((reach @ both) + reach > 0).astype(float)
        if np.array_equal(grown, reach):
            break
        reach = grown
    return observed & reach[:, 0, :].all(axis=1)


def _shaped(values: np.ndarray, shape: tuple[int, ...], name: str, dtype: type) -> np.ndarray:
    arr: np.ndarray = np.asarray(values, dtype=dtype)
    if arr.shape != shape:
        raise SwarmInputError(f"{name} must have shape {shape}, got {arr.shape}")
    return arr


def _valid(prior_poses: np.ndarray, prior_cov: np.ndarray, commands: np.ndarray, moving: np.ndarray, seen: np.ndarray,
           ranges: np.ndarray, bearings: np.ndarray) -> np.ndarray:
    """(B,) samples whose values the single-swarm constructors accept (finite, no negative drive or range)."""
    cmd = np.where(moving[..., None], commands, 0.0)
    with np.errstate(invalid="ignore"):
        bad_obs = seen & ~((ranges >= 0.0) & (ranges < np.inf) & np.isfinite(bearings))
        return cast(
            np.ndarray,
            np.isfinite(prior_poses).all(axis=(1, 2))
            & np.isfinite(prior_cov).all(axis=(1, 2, 3))
            & np.isfinite(cmd).all(axis=(1, 2))
            & (cmd[..., 1] >= 0).all(axis=1)
            & ~bad_obs.any(axis=(1, 2)),
        )


# --------------------------------------------------------------------------------------------
# The batched problems for ``sparse_lm.drive`` (``BatchOps``): states are dicts of per-sample arrays held in workspace slots


class _Workspace:
    """Scratch arrays reused across Newton iterations (fresh large arrays cost page faults every time)."""

    def __init__(self) -> None:
        self.arrays: dict[str, np.ndarray] = {}
        self.groups: dict[tuple[int, tuple[str, ...]], list[np.ndarray]] = {}

    def __call__(self, name: str, shape: tuple[int, ...]) -> np.ndarray:
        arr = self.arrays.get(name)
        if arr is None or arr.shape != shape:
            arr = self.arrays[name] = np.empty(shape)
        return arr

    def group(self, key: tuple[int, tuple[str, ...]], shape: tuple[int, ...]) -> list[np.ndarray]:
        """Arrays of one shape, one per name of ``key`` (slot, names), in one lookup."""
        arrs = self.groups.get(key)
        if arrs is None or arrs[0].shape != shape:
            arrs = self.groups[key] = [np.empty(shape) for _ in key[1]]
        return arrs


# ``_localize_paper`` or ``_localize_joint``: (cfg, dead-reckoning poses and covariances, seen, ranges, bearings, workspace)
_Solver: TypeAlias = Callable[[ModelConfig, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, _Workspace], _Solved]


class _Batched:
    """A problem whose array attributes all have the batch as their first axis, with a workspace."""

    ws: _Workspace

    def subset(self, index: np.ndarray) -> Self:
        out = object.__new__(type(self))
        for key, value in vars(self).items():
            setattr(out, key, value[index] if isinstance(value, np.ndarray) else value)
        out.ws = _Workspace()
        return out

    def _state(self, slot: int, names: tuple[str, ...], shape: tuple[int, ...]) -> list[np.ndarray]:
        """The workspace arrays of state ``slot``."""
        return self.ws.group((slot, names), shape)


def _newton_step(lap: np.ndarray, diag_x: np.ndarray, ct: np.ndarray, d: np.ndarray, g_xy: np.ndarray, g_theta: np.ndarray,
                 mu: np.ndarray, ws: _Workspace) -> tuple[np.ndarray, np.ndarray]:
    """Solve [[A + mu diag(diag_x), C], [C^T, diag(d)]] [dxy; dtheta] = -[g_xy; g_theta] per sample.

    Positions are ordered x of every robot, then y (index k n + a). A (B, 2n, 2n) is the
    position block, ``ct`` = C^T (B, n, 2n) the heading-position block, d (B, n) the (damped)
    heading diagonal. The headings are eliminated: (A - C D^-1 C^T) dxy = C D^-1 g_theta - g_xy.
    Returns the step (B, n, 3) and its predicted decrease -g.dx / 2 (B,) (``sparse_lm.minimize``'s ptol).
    """
    b, n, n2 = ct.shape
    ctd = np.divide(ct, d[:, :, None], out=ws("ctd", ct.shape))
    s = np.matmul(ct.swapaxes(1, 2), ctd, out=ws("schur", (b, n2, n2)))
    np.subtract(lap, s, out=s)
    s.reshape(b, n2 * n2)[:, :: n2 + 1] += mu[:, None] * diag_x
    rhs = np.matmul(g_theta[:, None, :], ctd)[:, 0, :] - g_xy
    dxy = _solve_stack(s, rhs)
    dtheta = (-g_theta - np.matmul(ct, dxy[:, :, None])[:, :, 0]) / d
    predicted = -0.5 * (np.einsum("bk,bk->b", g_xy, dxy) + np.einsum("bk,bk->b", g_theta, dtheta))
    step = ws("step", (b, n, 3))
    step[:, :, 0], step[:, :, 1], step[:, :, 2] = dxy[:, :n], dxy[:, n:], dtheta
    return step, predicted


def _solve_stack(a: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """Solve a (B, k, k) x = rhs (B, k) or (B, k, c); samples with a singular matrix get NaN (their step is then rejected)."""
    columns = rhs if rhs.ndim == 3 else rhs[..., None]
    try:
        out = np.linalg.solve(a, columns)
    except np.linalg.LinAlgError:
        out = np.full(columns.shape, np.nan)
        for k in range(len(a)):  # rare path: find the singular samples
            try:
                out[k] = np.linalg.solve(a[k], columns[k])
            except np.linalg.LinAlgError:
                pass
    return out if rhs.ndim == 3 else out[..., 0]


def _diagonal(a: np.ndarray) -> np.ndarray:
    """Writable view of the diagonals (B, n) of a stack of square matrices (B, n, n) (a may be a column slice)."""
    b, n, _ = a.shape
    return np.lib.stride_tricks.as_strided(a, (b, n), (a.strides[0], a.strides[1] + a.strides[2]), writeable=True)


def _on_pairs(seen: np.ndarray, values: np.ndarray) -> np.ndarray:
    """``values`` where ``seen``, 0 elsewhere (values there may be NaN)."""
    out = np.zeros(seen.shape)
    out[seen] = values[seen]
    return out


# --------------------------------------------------------------------------------------------
# The paper's method: topology (Eq. B2-B6), superimposition (Eq. 21-22), midpoint (Eq. 23)


class _TopologyProblem(_Batched):
    """Eq. B3 in the reference robot's frame: r_ij = R(theta_i) z_ij + x_i - x_j for every seen (i, j)
    (``topology_terms.observation_residuals``, the single-swarm problem's, on the dense (B, n, n) pair arrays).

    Fixed unknowns: the reference robot's pose (gauge) and the heading of robots that observed nobody.
    """

    def __init__(self, w: np.ndarray, zx: np.ndarray, zy: np.ndarray, ref: np.ndarray, has_heading: np.ndarray, ws: _Workspace) -> None:
        b, n, _ = w.shape
        rows = np.arange(b)
        self.w, self.zx, self.zy, self.ref, self.ws = w, zx, zy, ref, ws
        self.free_head = has_heading.astype(float)
        self.free_head[rows, ref] = 0.0
        # J^T J of the positions does not depend on the unknowns: a graph Laplacian per axis.
        both = w + w.swapaxes(1, 2)
        degree = np.einsum("bij->bi", both)
        lap = np.zeros((b, 2 * n, 2 * n))
        for k in (0, n):
            block = lap[:, k : k + n, k : k + n]
            np.negative(both, out=block)
            _diagonal(block)[:] = degree
            block[rows, ref, :] = 0.0  # the reference position is fixed: identity row and column
            block[rows, :, ref] = 0.0
            block[rows, ref, ref] = 1.0
        self.lap = lap
        diag_x = damping_scale(degree)
        diag_x[rows, ref] = 0.0
        self.diag_x = np.concatenate([diag_x, diag_x], axis=1)
        self.h_theta = np.einsum("bij->bi", zx * zx + zy * zy)  # |d r_ij / d theta_i|^2 = rho_ij^2
        self.diag_theta = damping_scale(self.h_theta)

    def evaluate(self, x: np.ndarray, slot: int = 0) -> dict[str, np.ndarray]:
        out = self._state(slot, ("rzx", "rzy", "rx", "ry"), self.w.shape)
        c, s = np.cos(x[:, :, 2])[:, :, None], np.sin(x[:, :, 2])[:, :, None]
        xi, xj = x[:, :, None, :2], x[:, None, :, :2]
        # R(theta_i) z_ij (zero where (i, j) unseen) and r_ij = R z_ij + x_i - x_j, kept where seen
        rzx, rzy, rx, ry = topology_residuals(
            c, s, self.zx, self.zy, xi[..., 0], xi[..., 1], xj[..., 0], xj[..., 1], out=out, scratch=self.ws("tmp", self.w.shape)
        )
        rx *= self.w
        ry *= self.w
        cost = 0.5 * (np.einsum("bij,bij->b", rx, rx) + np.einsum("bij,bij->b", ry, ry))
        return {"cost": cost, "rzx": rzx, "rzy": rzy, "rx": rx, "ry": ry}

    def step(self, st: dict[str, np.ndarray], mu: np.ndarray, curved: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        rzx, rzy, rx, ry = st["rzx"], st["rzy"], st["rx"], st["ry"]
        b, n, _ = rx.shape
        rows, fh, ref = np.arange(b), self.free_head, self.ref
        # Gradient J^T r with d r_ij / d theta_i = ``topology_terms.observation_jacobian``, d / d x_i = I, d / d x_j = -I.
        jx, jy = topology_jacobian(rzx, rzy, self.ws("jtx", rx.shape))
        g_theta = fh * (np.einsum("bij,bij->bi", jx, rx) + np.einsum("bij,bij->bi", jy, ry))
        g_xy = np.concatenate(
            [np.einsum("bij->bi", rx) - np.einsum("bij->bj", rx), np.einsum("bij->bi", ry) - np.einsum("bij->bj", ry)], axis=1
        )
        g_xy[rows, ref] = g_xy[rows, n + ref] = 0.0
        # Heading diagonal: J^T J + the exact second-order term (``topology_terms.heading_curvature``), clamped as
        # sparse_lm (and, as there, left out of a sample's first iteration).
        second = np.einsum("bij->bi", heading_curvature(rzx, rzy, rx, ry))
        d = self.h_theta + curved[:, None] * clamp_curvature(second, self.diag_theta) + mu[:, None] * self.diag_theta
        d = fh * d + (1.0 - fh)
        # C^T[i, (k, a)] = delta_ai sum_j (d r_ij / d theta_i)_k - (d r_ia / d theta_i)_k.
        ct = self.ws("ct", (b, n, 2 * n))
        np.negative(jx, out=ct[:, :, :n])
        np.negative(jy, out=ct[:, :, n:])
        _diagonal(ct[:, :, :n])[:] = np.einsum("bij->bi", jx)
        _diagonal(ct[:, :, n:])[:] = np.einsum("bij->bi", jy)
        ct[rows, :, ref] = ct[rows, :, n + ref] = 0.0  # fixed reference position
        ct[rows, ref, :] = 0.0  # fixed reference heading
        return _newton_step(self.lap, self.diag_x, ct, d, g_xy, g_theta, mu, self.ws)


def _localize_paper(cfg: ModelConfig, dr_poses: np.ndarray, dr_cov: np.ndarray, seen: np.ndarray, ranges: np.ndarray,
                    bearings: np.ndarray, ws: _Workspace) -> _Solved:
    b, n, _ = dr_poses.shape
    w = seen.astype(float)
    made = np.einsum("bij->bi", w)
    has_heading = made > 0
    ref = reference_robot(made)
    rho = _on_pairs(seen, ranges)
    z = observation_offsets(rho[seen], bearings[seen])  # Eq. B1, seen pairs only
    zx, zy = np.zeros(seen.shape), np.zeros(seen.shape)
    zx[seen], zy[seen] = z[:, 0], z[:, 1]
    start = to_reference_frame(dr_poses, dr_poses[np.arange(b), ref])
    start[:, :, 2] *= has_heading
    x, good, _, _ = drive(_TopologyProblem(w, zx, zy, ref, has_heading, ws), start, *PAPER_TOL, xp=BatchOps)

    # Eq. B4: cluster points R(theta_i) z_ij + x_i of the observed robots j; Eq. B6.
    theta = wrap_angle(x[:, :, 2])
    c, s = np.cos(theta)[:, :, None], np.sin(theta)[:, :, None]
    px = w * (c * zx - s * zy + x[:, :, None, 0])
    py = w * (s * zx + c * zy + x[:, :, None, 1])
    count = np.einsum("bij->bj", w)
    safe = np.maximum(count, 1.0)
    centroid = np.stack([np.einsum("bij->bj", px), np.einsum("bij->bj", py)], axis=2) / safe[:, :, None]
    sq = np.stack([np.einsum("bij,bij->bj", px, px), np.einsum("bij,bij->bj", py, py)], axis=2)
    mean_range = np.einsum("bij->bj", rho) / safe
    delta_p = cluster_delta_p(count, centroid, sq, mean_range, cfg)
    centroid = np.where(count[:, :, None] > 0, centroid, x[:, :, :2])
    headings = np.where(has_heading, theta, np.nan)

    # Phase 2 (Eq. 21-23).
    delta_u = np.sqrt(np.maximum(dr_cov[:, :, 0, 0] + dr_cov[:, :, 1, 1], 0.0))
    with np.errstate(invalid="ignore", divide="ignore"):
        weights = fusion_weights(delta_p, delta_u)
        good &= np.all(np.isfinite(weights) & (weights > 0), axis=1)
        weights = np.where(good[:, None], weights, 1.0)
        rot, t, spread = weighted_procrustes(centroid, dr_poses[:, :, :2], weights)
        good &= spread > MIN_SPREAD
    poses, cov = fuse(centroid, headings, delta_p, heading_sigmas(made, cfg), rot, t, dr_poses, dr_cov, delta_u)
    return poses, cov, good


# --------------------------------------------------------------------------------------------
# Joint least squares: whitened dead-reckoning priors + range/bearing residuals


@functools.cache
def _lap_diagonal(n: int) -> np.ndarray:
    """Flat indices into (2n, 2n) of the diagonals of its four (n, n) blocks, in (block row, robot, block column) order."""
    r, i, c = np.meshgrid(np.arange(2), np.arange(n), np.arange(2), indexing="ij")
    return ((r * n + i) * 2 * n + c * n + i).ravel()


@functools.cache
def _ct_diagonal(n: int) -> np.ndarray:
    """Flat indices into (n, 2n) of the diagonals of its two (n, n) blocks, in (robot, block) order."""
    i, k = np.meshgrid(np.arange(n), np.arange(2), indexing="ij")
    return (i * 2 * n + k * n + i).ravel()


@functools.cache
def _orders(n: int) -> tuple[np.ndarray, np.ndarray]:
    """(to_robots, to_batch): the batch index (x of every robot, then y, then headings) of robot-order index 3 a + c
    (x_0, y_0, heading_0, x_1, ...), and its inverse permutation."""
    to_robots = (np.arange(3)[None, :] * n + np.arange(n)[:, None]).ravel()
    return to_robots, np.argsort(to_robots)


@functools.cache
def _robot_blocks(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Flat indices into a (2n, 2n) position block of each robot's 2x2 block (n, 2, 2), and into a (2n, n) matrix of
    each robot's (x, y) entries in its own column (n, 2)."""
    i, k, m = np.meshgrid(np.arange(n), np.arange(2), np.arange(2), indexing="ij")
    i2, k2 = np.meshgrid(np.arange(n), np.arange(2), indexing="ij")
    return (k * n + i) * 2 * n + m * n + i, (k2 * n + i2) * n + i2


@functools.cache
def _off_diagonal(n: int) -> np.ndarray:
    """(n, n) True off the diagonal."""
    return ~np.eye(n, dtype=bool)


class _JointProblem(_Batched):
    """Whitened prior residuals W_i (p_i - mu_i) and range/bearing residuals of every seen (i, j).

    Only W^T W enters (cost, gradient, J^T J), so W itself is not needed.

    The observation residuals are ``range_bearing.observation_residuals`` (the single-swarm problem's) on the
    dense (B, n, n) pair arrays, zero where unseen; the prior's difference is ``range_bearing.pose_difference``.
    """

    def __init__(self, seen: np.ndarray, ranges: np.ndarray, bearings: np.ndarray, mean: np.ndarray, info: np.ndarray, s_r: float,
                 cfg: ModelConfig, ws: _Workspace) -> None:
        self.ws = ws
        w = seen.astype(float)
        self.rho = _on_pairs(seen, ranges)
        self.w_sr, self.w_sb = w / s_r, w * bearing_weights(self.rho, cfg)  # 1 / s_b(rho) where seen, 0 elsewhere
        phi = bearings[seen]
        self.cphi, self.sphi = np.zeros(seen.shape), np.zeros(seen.shape)
        self.cphi[seen], self.sphi[seen] = np.cos(phi), np.sin(phi)
        self.mean, self.info = mean, info  # W^T W of the whitened prior residuals W (p - mu)
        self.d_theta = np.einsum("bij,bij->bi", self.w_sb, self.w_sb) + self.info[:, :, 2, 2]  # heading block of J^T J (diagonal): w_b^2
        self.d_scale = damping_scale(self.d_theta)  # the headings' damping scale (their block does not change)

    def evaluate(self, x: np.ndarray, slot: int = 0) -> dict[str, np.ndarray]:
        shape = self.rho.shape
        dx, dy, inv_dist, r_range, r_bearing = self._state(slot, ("dx", "dy", "inv_dist", "rr", "rb"), shape)
        t1, t2, t3, t4, t5 = self._state(-1, ("t1", "t2", "t3", "t4", "t5"), shape)  # scratch
        np.subtract(x[:, None, :, 0], x[:, :, None, 0], out=dx)  # [b, i, j] = x_j - x_i
        np.subtract(x[:, None, :, 1], x[:, :, None, 1], out=dy)
        c, s = np.cos(x[:, :, 2])[:, :, None], np.sin(x[:, :, 2])[:, :, None]
        ca = np.multiply(c, self.cphi, out=t1)  # cos(theta_i + phi_ij), 0 where unseen
        ca -= np.multiply(s, self.sphi, out=t2)
        sa = np.multiply(s, self.cphi, out=t2)
        sa += np.multiply(c, self.sphi, out=t3)
        # (|d| - rho) / s_r and the bearing residual where seen; unseen pairs hold atan2(+-0, +-0) x 0: masked
        observation_residuals(dx, dy, self.rho, self.w_sr, self.w_sb, cos_sin=(ca, sa), out=(r_range, r_bearing, inv_dist), scratch=(t3, t4, t5))
        np.divide(1.0, inv_dist, out=inv_dist)  # |d| -> 1 / |d|
        diff = pose_difference(x, self.mean)
        g_prior = np.einsum("bnij,bnj->bni", self.info, diff)  # W^T W (p - mu): gradient of the prior terms
        cost = 0.5 * (
            np.einsum("bni,bni->b", diff, g_prior)
            + np.einsum("bij,bij->b", r_range, r_range)
            + np.einsum("bij,bij->b", r_bearing, r_bearing)
        )
        return {"cost": cost, "dx": dx, "dy": dy, "inv_dist": inv_dist, "rr": r_range, "rb": r_bearing, "gp": g_prior}

    def normal(self, st: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """J^T J as (position block (B, 2n, 2n), heading-position block C^T (B, n, 2n), heading diagonal (B, n)).

        From each pair's Jacobian (``range_bearing.observation_jacobian``, kept in the workspace for ``step``):
        its position block is J_j^T J_j over (range, bearing), its heading-position entries
        d bearing / d theta_i = -w_b times d bearing / d x_j.
        """
        ws, info = self.ws, self.info
        shape = st["inv_dist"].shape
        b, n, _ = shape
        jac = ws("jac", (4, b, n, n))  # d range / d x_j, d range / d y_j, d bearing / d x_j, d bearing / d y_j of every pair
        observation_jacobian(st["dx"], st["dy"], st["inv_dist"], self.w_sr, self.w_sb, out=list(jac))
        # the 2x2 position blocks of every pair at once: a[r, c] = J_r J_c over (range, bearing); (1, 0) is (0, 1)
        a = np.multiply(jac[:2, None], jac[None, :2], out=ws("n22", (2, 2) + shape))
        a += np.multiply(jac[2:, None], jac[None, 2:], out=ws("m22", (2, 2) + shape))
        both = np.add(a, a.swapaxes(-1, -2), out=ws("m22", (2, 2) + shape))  # robots a and c meet as observer and as observed
        lap = ws("lap", (b, 2 * n, 2 * n))
        np.negative(both.transpose(2, 0, 3, 1, 4), out=lap.reshape(b, 2, n, 2, n))
        lap.reshape(b, 4 * n * n)[:, _lap_diagonal(n)] = (np.einsum("rcbij->bric", both) + info[:, :, :2, :2].transpose(0, 2, 1, 3)).reshape(b, 4 * n)
        # C^T[i, (k, a)] = delta_ai (sum_j q_ij,k + info) - q_ia,k with q = w_b d bearing / d x_j.
        q = np.multiply(self.w_sb, jac[2:], out=ws("n2", (2,) + shape))
        ct = ws("ct", (b, n, 2 * n))
        np.negative(q.transpose(1, 2, 0, 3), out=ct.reshape(b, n, 2, n))
        ct.reshape(b, 2 * n * n)[:, _ct_diagonal(n)] = (np.einsum("kbij->bik", q) + info[:, :, :2, 2]).reshape(b, 2 * n)
        return lap, ct, self.d_theta

    def step(self, st: dict[str, np.ndarray], mu: np.ndarray, curved: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        ws = self.ws
        lap, ct, d = self.normal(st)
        b, n, n2 = ct.shape
        shape = st["inv_dist"].shape
        jac = ws.arrays["jac"]  # ``normal``'s
        g_prior = st["gp"]
        # q = (d r / d x_j)^T r of each pair, x and y at once (d / d x_i = -d / d x_j)
        q = np.multiply(jac[:2], st["rr"], out=ws("n2", (2,) + shape))
        q += np.multiply(jac[2:], st["rb"], out=ws("m2", (2,) + shape))
        g_xy = (np.einsum("kbij->bkj", q) - np.einsum("kbij->bki", q) + g_prior[:, :, :2].swapaxes(1, 2)).reshape(b, n2)
        g_theta = g_prior[:, :, 2] - np.einsum("bij,bij->bi", st["rb"], self.w_sb)  # d bearing / d theta_i = -w_b
        diag_x = damping_scale(lap.reshape(b, n2 * n2)[:, :: n2 + 1])
        d_damped = d + mu[:, None] * self.d_scale
        return _newton_step(lap, diag_x, ct, d_damped, g_xy, g_theta, mu, ws)


def _localize_joint(cfg: ModelConfig, dr_poses: np.ndarray, dr_cov: np.ndarray, seen: np.ndarray, ranges: np.ndarray,
                    bearings: np.ndarray, ws: _Workspace, constrain: bool, keep: np.ndarray | None = None,
                    covariances: bool = True) -> _Solved:
    """``JointLocalizer._solve`` of every sample: the least-squares solution and its covariances, or with ``constrain``
    the observability-constrained update's (``gauge``; ``keep`` (B, n): the robots localized where not all).
    ``covariances=False``: the poses alone (to rounding), the covariances NaN."""
    s_r, _ = sensor_sigmas(cfg)
    problem = _JointProblem(seen, ranges, bearings, dr_poses, prior_information(dr_cov), s_r, cfg, ws)
    x, good, _, st = drive(problem, dr_poses, *JOINT_TOL, xp=BatchOps)  # st: every sample's state at x
    wrong = np.flatnonzero(good & implausible(st["cost"], seen.sum(axis=(1, 2))))
    if wrong.size and _rescue(cfg, problem, x, st["cost"], wrong, seen, ranges, bearings, dr_poses, dr_cov):
        st = problem.evaluate(x)
    cov: np.ndarray | None
    if constrain:
        x, cov = _constrained_update(problem.info, st["gp"], *problem.normal(st), x, dr_poses, keep, covariances)
    else:
        cov = _joint_covariances(*problem.normal(st)) if covariances else None
    x[:, :, 2] = wrap_angle(x[:, :, 2])
    good &= np.isfinite(x).all(axis=(1, 2))
    if cov is None:  # the poses alone: every quantity the covariances come from is finite where the poses are
        return x, np.full(dr_cov.shape, np.nan), good
    cov = psd(cov)
    good &= np.isfinite(cov).all(axis=(1, 2, 3))
    return x, cov, good


def _rescue(cfg: ModelConfig, problem: _JointProblem, x: np.ndarray, cost: np.ndarray, wrong: np.ndarray, seen: np.ndarray,
            ranges: np.ndarray, bearings: np.ndarray, dr_poses: np.ndarray, dr_cov: np.ndarray) -> bool:
    """``JointLocalizer._solve``'s second solve of samples ``wrong`` (an implausible cost: a wrong local minimum) from
    ``joint.rescue_start``, into x where its cost is lower; the robots without observations stay at the prior mean,
    as they are not in the single-swarm problem. Returns whether any sample took it."""
    starts, tried = dr_poses[wrong].copy(), np.zeros(wrong.size, bool)
    for k, b in enumerate(wrong):
        i, j = np.nonzero(seen[b])
        kept = np.zeros(seen.shape[1], bool)
        kept[i], kept[j] = True, True
        obs = Observations(i, j, ranges[b, i, j], bearings[b, i, j])  # robot ids = their indices, as in ``_localize_each``
        start = rescue_start(cfg, np.flatnonzero(kept), obs, dr_poses[b, kept], dr_cov[b, kept])
        if start is not None:
            starts[k, kept], tried[k] = start, True
    wrong, starts = wrong[tried], starts[tried]
    if not wrong.size:
        return False
    sub = problem.subset(wrong)
    again, converged, _, _ = drive(sub, starts, *JOINT_TOL, xp=BatchOps)
    better = converged & (sub.evaluate(again)["cost"] < cost[wrong])
    x[wrong[better]] = again[better]
    return bool(better.any())


def _constrained_update(prior_info: np.ndarray, prior_gradient: np.ndarray, lap: np.ndarray, ct: np.ndarray, d: np.ndarray,
                        x: np.ndarray, mean: np.ndarray, keep: np.ndarray | None,
                        covariances: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
    """Poses (B, n, 3) and covariances (B, n, 3, 3) of the observability-constrained update (``gauge``, as
    ``JointLocalizer``), without any (3n, 3n) matrix: the correction U K U^T of ``gauge_correction`` (of the robots
    ``keep``, None: all) enters the inverse of J^T J = A by the Woodbury identity,
    (A + U K U^T)^-1 = A^-1 - L (K^-1 + U^T L)^-1 L^T with L = A^-1 U, A^-1 applied through the Schur complement;
    the estimate moves by ``constrained_solution``'s step (its ``gauge_gradient``), the covariance blocks by
    ``transported_blocks`` about the whole swarm's predicted gauge.

    ``prior_info`` (B, n, 3, 3) and ``prior_gradient`` (B, n, 3) are the prior's share of J^T J and J^T r at ``x``;
    ``lap``, ``ct``, ``d`` J^T J in the batch's order (x of every robot, then y, then headings:
    ``_JointProblem.normal``); the gauge's (N, Pi) and the prior's gradient are moved from their robot-by-robot order
    (x_0, y_0, heading_0, x_1, ...) into it, and the results back. ``covariances=False``: the poses alone (S^-1 U and
    m g by solves instead of S^-1 and m: the same poses to rounding), the covariances None.
    """
    b, n, n2 = ct.shape
    k = 3 * n
    if covariances:
        parts = _schur_parts(lap, ct, d)
        ctd, s_inv, _ = parts
    else:  # the poses need S^-1 applied to U's six columns only: solved, not inverted
        with np.errstate(divide="ignore", invalid="ignore"):
            ctd = ct / d[:, :, None]
            schur = lap - np.matmul(ct.swapaxes(1, 2), ctd)
    to_robots, to_batch = _orders(n)

    def inverse_times(m: np.ndarray) -> np.ndarray:  # A^-1 m (m (B, 3n, c) in the batch's order) through the Schur complement S = lap - C D^-1 C^T
        rhs = m[:, :n2] - ctd.swapaxes(1, 2) @ m[:, n2:]
        y = s_inv @ rhs if covariances else _solve_stack(schur, rhs)
        return np.concatenate([y, m[:, n2:] / d[:, :, None] - ctd @ y], axis=1)

    def batch_order(frame: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:  # (N, Pi) in the batch's order
        return frame[0][:, to_batch], frame[1][:, :, to_batch]

    robot_frame = gauge_frame(mean, keep)
    basis, proj = frame = batch_order(robot_frame)
    # S N with S = H^T H = J^T J minus the prior's (block-diagonal) information
    prior_n = (prior_info @ robot_frame[0].reshape(b, n, 3, 3)).reshape(b, k, 3)[:, to_batch]
    sn = np.concatenate([lap @ basis[:, :n2] + ct.swapaxes(1, 2) @ basis[:, n2:], ct @ basis[:, :n2] + d[:, :, None] * basis[:, n2:]], axis=1)
    u, kmat = gauge_correction(sn - prior_n, frame)  # the correction U K U^T
    low = inverse_times(u)  # L = A^-1 U
    small = _EYE6 + kmat @ (u.swapaxes(1, 2) @ low)
    # C = A^-1 - L m: the estimate (``constrained_solution``: x - C Pi^T N^T g, A^-1 Pi^T = L's last three columns)
    along = gauge_gradient(prior_gradient.reshape(b, k)[:, to_batch], frame)  # N^T g
    g = (along[:, None, :] @ proj)[:, 0]  # Pi^T N^T g
    dense = _ill_conditioned(small)
    if not covariances:  # m g alone: (I + K U^T L)^-1 K L^T g, one right-hand side
        with np.errstate(invalid="ignore"):
            mg = _solve_stack(small, (kmat @ (low.swapaxes(1, 2) @ g[:, :, None]))[:, :, 0])
        step = (low[:, :, 3:] @ along[:, :, None])[:, :, 0] - (low @ mg[:, :, None])[:, :, 0]
        poses = x - step[:, to_robots].reshape(b, n, 3)
        for s in dense:  # the single-swarm localizer's dense update
            poses[s] = _dense_update(prior_info[s], prior_gradient[s], lap[s], ct[s], d[s], x[s], mean[s], None if keep is None else keep[s])[0]
        return poses, None
    with np.errstate(invalid="ignore"):
        try:  # m = (K^-1 + U^T L)^-1 L^T = (I + K U^T L)^-1 K L^T, (B, 6, 3n)
            m = np.linalg.solve(small, kmat @ low.swapaxes(1, 2))
        except np.linalg.LinAlgError:
            m = np.full((b, 6, k), np.nan)
    step = (low[:, :, 3:] @ along[:, :, None] - low @ (m @ g[:, :, None]))[:, :, 0]
    poses = x - step[:, to_robots].reshape(b, n, 3)
    low_a = low[:, to_robots].reshape(b, n, 3, 6)
    blocks = _joint_covariances(lap, ct, d, parts) - low_a @ np.swapaxes(m[:, :, to_robots].reshape(b, 6, n, 3), 1, 2)
    if keep is None:
        whole, inv_pt = robot_frame, low[:, :, 3:]  # A^-1 Pi^T: U holds Pi^T
    else:  # transported about the whole swarm's gauge
        whole = gauge_frame(mean)
        proj = batch_order(whole)[1]
        inv_pt = inverse_times(proj.swapaxes(1, 2))
    pc = inv_pt.swapaxes(1, 2) - (proj @ low) @ m  # Pi C = Pi A^-1 - Pi L m
    pcp = pc @ proj.swapaxes(1, 2)
    blocks = transported_blocks(blocks, transport_offset(mean, poses, whole), pc[:, :, to_robots], pcp)
    for s in dense:  # the Woodbury identity has lost the digits: the single-swarm localizer's dense update
        poses[s], blocks[s] = _dense_update(prior_info[s], prior_gradient[s], lap[s], ct[s], d[s], x[s], mean[s], None if keep is None else keep[s])
    return poses, blocks


def _dense_update(prior_info: np.ndarray, prior_gradient: np.ndarray, lap: np.ndarray, ct: np.ndarray, d: np.ndarray, x: np.ndarray,
                  mean: np.ndarray, keep: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """One sample's observability-constrained update as the single-swarm localizer does it, with the whole (3n, 3n)
    covariance: (poses (n, 3), covariance blocks (n, 3, 3)); arguments as ``_constrained_update``'s, of one sample."""
    n = len(d)
    to_robots = _orders(n)[0]
    full = np.block([[lap, ct.swapaxes(0, 1)], [ct, np.diag(d)]])[np.ix_(to_robots, to_robots)]
    observed = full - block_diagonal(prior_info)
    own = gauge_frame(mean, keep)
    cov = constrained_covariance(full, observed, mean, own)
    poses = constrained_solution(x, mean, cov, prior_gradient.ravel(), own)
    cov = transport(cov, mean, poses, gauge_frame(mean))
    idx = np.arange(3 * n).reshape(n, 3)
    return poses, cov[idx[:, :, None], idx[:, None, :]]


def _ill_conditioned(small: np.ndarray) -> np.ndarray:
    """Indices of the matrices of a (B, k, k) stack whose 2-norm condition number is above ``WOODBURY_COND_LIMIT`` or not
    finite: ``np.linalg.cond`` (an SVD, ~4 us a 6x6 matrix), taken only where the bound cond_2 <= ||A||_F ||A^-1||_F
    (one inverse, ~1 us) is not below half the limit, so the answer is the SVD's everywhere (the factor 2 covers the
    rounding of the bound, relative ~cond x 1e-16)."""
    with np.errstate(invalid="ignore", over="ignore"):
        inverse = _inv_stack(small)
        bound = np.sqrt(np.einsum("bij,bij->b", small, small) * np.einsum("bij,bij->b", inverse, inverse))
        unsure = np.flatnonzero(~(bound <= 0.5 * WOODBURY_COND_LIMIT))
        if not unsure.size:
            return unsure
        return cast(np.ndarray, unsure[~(np.linalg.cond(small[unsure]) <= WOODBURY_COND_LIMIT)])


def _schur_parts(lap: np.ndarray, ct: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(D^-1 C^T, S^-1, S^-1 C D^-1) of J^T J = [[lap, C], [C^T, diag(d)]] (``ct`` = C^T), S = lap - C D^-1 C^T: the
    inverse is [[S^-1, -S^-1 C D^-1], [., D^-1 + D^-1 C^T S^-1 C D^-1]]. NaN where singular."""
    with np.errstate(divide="ignore", invalid="ignore"):
        ctd = ct / d[:, :, None]
        s_inv = _inv_stack(lap - np.matmul(ct.swapaxes(1, 2), ctd))  # position block of the inverse
        e = np.matmul(s_inv, ctd.swapaxes(1, 2))  # S^-1 C D^-1 = -(position-heading block of the inverse)
    return ctd, s_inv, e


def _joint_covariances(lap: np.ndarray, ct: np.ndarray, d: np.ndarray, parts: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """3x3 diagonal blocks (B, n, 3, 3) of the inverse of J^T J = [[lap, C], [C^T, diag(d)]] (``ct`` = C^T).

    Exact up to ``EXACT_COV_LIMIT`` robots (``_schur_parts``, or ``parts`` when the caller has them); above, each
    robot's 3x3 information block is inverted alone, like ``joint.pose_covariances``.
    """
    b, n, n2 = ct.shape
    cov = np.empty((b, n, 3, 3))
    if n > EXACT_COV_LIMIT:  # conditional covariances
        i = np.arange(n)
        for k in (0, 1):
            for m in (0, 1):
                cov[:, :, k, m] = lap[:, k * n + i, m * n + i]
            cov[:, :, k, 2] = cov[:, :, 2, k] = ct[:, i, k * n + i]
        cov[:, :, 2, 2] = d
        return _inv_stack(cov)
    ctd, s_inv, e = _schur_parts(lap, ct, d) if parts is None else parts
    position, position_heading = _robot_blocks(n)
    cov[:, :, :2, :2] = s_inv.reshape(b, 4 * n * n)[:, position]
    np.negative(e.reshape(b, 2 * n * n)[:, position_heading], out=cov[:, :, :2, 2])
    cov[:, :, 2, :2] = cov[:, :, :2, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        cov[:, :, 2, 2] = 1.0 / d + np.einsum("bir,bri->bi", ctd, e)  # D^-1 + D^-1 C^T S^-1 C D^-1
    return cov


def _inv_stack(a: np.ndarray) -> np.ndarray:
    """Inverse of each (k, k) matrix of a stack; NaN for singular ones."""
    try:
        return np.linalg.inv(a)
    except np.linalg.LinAlgError:
        out = np.full(a.shape, np.nan)
        for k in range(len(a)):
            try:
                out[k] = np.linalg.inv(a[k])
            except np.linalg.LinAlgError:
                pass
        return out
