"""Data passed between motion, sensing and localization (SI units throughout).

* ``SwarmEstimate``: poses (n, 3) = (x m, y m, heading rad) with a 3x3 covariance per robot
  and, optionally, the joint (3n, 3n) covariance of the whole swarm (cross-correlations).
* ``StepCommands``: one inchworm step's body-frame commands (turn rad, drive m).
* ``Observations``: range/bearing rows ``[observer, observed, range_m, bearing_rad]``,
  the bearing measured in the observer's body frame (Eq. 20).

Robot ids are arbitrary non-negative integers; arrays are ordered like ``ids``.
Constructors validate shapes, finiteness and ids and raise ``SwarmInputError``
naming the offending robots.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, cast

import numpy as np

from runtime.errors import SwarmInputError


def robot_ids(ids: np.ndarray | list[int]) -> np.ndarray:
    """Validated int64 robot ids: 1-D, integers >= 0, no duplicates."""
    arr = np.asarray(ids)
    if arr.ndim != 1 or (arr.size and not np.issubdtype(arr.dtype, np.integer)):
        raise SwarmInputError(f"robot ids must be a 1-D list of integers, got {ids!r}")
    arr = arr.astype(np.int64)
    uniq, counts = np.unique(arr, return_counts=True)
    if np.any(counts > 1):
        raise SwarmInputError(f"duplicate robot ids: {uniq[counts > 1].tolist()}")
    if np.any(arr < 0):
        raise SwarmInputError(f"robot ids must be >= 0, got {arr[arr < 0].tolist()}")
    return arr


def _bad_rows(values: np.ndarray) -> np.ndarray:
    """Indices of rows holding NaN or inf."""
    flat = values.reshape(values.shape[0], int(np.prod(values.shape[1:])))
    return np.flatnonzero(~np.all(np.isfinite(flat), axis=1))


def index_of(ids: np.ndarray, query: np.ndarray, what: str) -> np.ndarray:
    """Positions of ``query`` ids inside ``ids``; unknown ids raise naming them."""
    n, query = len(ids), np.asarray(query)
    if n and ids[0] == 0 and ids[-1] == n - 1 and np.issubdtype(query.dtype, np.integer) and np.all(ids[1:] > ids[:-1]):
        if np.all((query >= 0) & (query < n)):  # ids 0..n-1 in order (a simulated swarm's): a query is its position
            return query.astype(np.int64, copy=False)
    order = np.argsort(ids)
    pos = np.searchsorted(ids[order], query)
    pos = np.clip(pos, 0, len(ids) - 1)
    found = ids[order][pos] == query if len(ids) else np.zeros(len(query), bool)
    if not np.all(found):
        unknown = sorted(set(query[~found].tolist()))
        raise SwarmInputError(f"unknown robot ids in {what}: {unknown} (known: {ids.tolist()})")
    return order[pos]


@dataclass(frozen=True)
class SwarmEstimate:
    """Global poses of the swarm with per-robot uncertainty.

    ``cov[i]`` is the 3x3 covariance of (x, y, heading) of robot ``ids[i]``
    (m^2, m*rad, rad^2). ``delta`` is the paper's scalar position uncertainty
    sqrt(var_x + var_y) (as in Eq. B6), in metres.

    ``joint``, when known, is the (3n, 3n) covariance of all poses, ordered robot by robot
    (x_0, y_0, heading_0, x_1, ...); its 3x3 diagonal blocks are ``cov`` (``from_joint``).
    It carries the cross-correlations a localizer's next prior needs; None = robots
    treated as independent. ``select`` keeps it (a marginal is a sub-block).
    """

    ids: np.ndarray
    poses: np.ndarray
    cov: np.ndarray
    joint: np.ndarray | None = None

    def __post_init__(self) -> None:
        ids = robot_ids(self.ids)
        poses = np.asarray(self.poses, dtype=float)
        cov = np.asarray(self.cov, dtype=float)
        if poses.shape != (len(ids), 3):
            raise SwarmInputError(f"poses must have shape ({len(ids)}, 3), got {poses.shape}")
        if cov.shape != (len(ids), 3, 3):
            raise SwarmInputError(f"cov must have shape ({len(ids)}, 3, 3), got {cov.shape}")
        for name, arr in (("poses", poses), ("cov", cov)):
            bad = _bad_rows(arr)
            if bad.size:
                raise SwarmInputError(f"{name} hold NaN/inf for robots {ids[bad].tolist()}")
        object.__setattr__(self, "ids", ids)
        object.__setattr__(self, "poses", poses)
        object.__setattr__(self, "cov", cov)
        if self.joint is not None:
            joint = np.asarray(self.joint, dtype=float)
            if joint.shape != (3 * len(ids), 3 * len(ids)):
                raise SwarmInputError(f"joint covariance must have shape ({3 * len(ids)}, {3 * len(ids)}), got {joint.shape}")
            if not np.all(np.isfinite(joint)):
                raise SwarmInputError("joint covariance holds NaN/inf")
            object.__setattr__(self, "joint", joint)

    @classmethod
    def from_joint(cls, ids: np.ndarray | list[int], poses: np.ndarray, joint: np.ndarray) -> SwarmEstimate:
        """Estimate whose per-robot ``cov`` are the 3x3 diagonal blocks of ``joint`` (3n, 3n)."""
        n = len(ids)
        idx = np.arange(3 * n).reshape(n, 3)
        joint = np.asarray(joint, dtype=float)
        return cls(np.asarray(ids), poses, joint[idx[:, :, None], idx[:, None, :]], joint)

    @classmethod
    def derived(cls, of: SwarmEstimate, poses: np.ndarray, joint: np.ndarray) -> SwarmEstimate:
        """``from_joint`` for a new estimate of the robots of ``of`` (a localizer's output): their ids were
        validated when ``of`` was built, so only the shapes and finiteness of ``poses`` (n, 3) and
        ``joint`` (3n, 3n) are checked (``SwarmInputError`` otherwise)."""
        n = of.n
        poses, joint = np.asarray(poses, dtype=float), np.asarray(joint, dtype=float)
        if poses.shape != (n, 3) or joint.shape != (3 * n, 3 * n):
            raise SwarmInputError(f"a derived estimate of {n} robots needs poses (n, 3) and joint (3n, 3n), got {poses.shape} and {joint.shape}")
        if not (np.isfinite(poses).all() and np.isfinite(joint).all()):
            bad = _bad_rows(np.concatenate([poses, joint.reshape(n, -1)], axis=1))
            raise SwarmInputError(f"poses or joint covariance hold NaN/inf for robots {of.ids[bad].tolist()}")
        idx = np.arange(3 * n).reshape(n, 3)
        out = object.__new__(cls)
        for name, value in (("ids", of.ids), ("poses", poses), ("cov", joint[idx[:, :, None], idx[:, None, :]]), ("joint", joint)):
            object.__setattr__(out, name, value)
        return out

    @classmethod
    def isotropic(
        cls, ids: np.ndarray | list[int], poses: np.ndarray, delta: np.ndarray | float, sigma_heading: np.ndarray | float
    ) -> SwarmEstimate:
        """Estimate with position std ``delta`` (m, split equally over x and y) and heading std (rad)."""
        n = len(ids)
        cov = np.zeros((n, 3, 3))
        var_xy = np.broadcast_to(np.asarray(delta, float) ** 2 / 2.0, (n,))
        cov[:, 0, 0] = var_xy
        cov[:, 1, 1] = var_xy
        cov[:, 2, 2] = np.broadcast_to(np.asarray(sigma_heading, float) ** 2, (n,))
        return cls(np.asarray(ids), np.asarray(poses, float), cov)

    @property
    def n(self) -> int:
        return len(self.ids)

    @property
    def positions(self) -> np.ndarray:
        """Configuration C (Eq. 5): positions (n, 2) in metres."""
        return self.poses[:, :2]

    @property
    def delta(self) -> np.ndarray:
        """Scalar position uncertainty per robot, sqrt(var_x + var_y) (m)."""
        return cast(np.ndarray, np.sqrt(np.maximum(self.cov[:, 0, 0] + self.cov[:, 1, 1], 0.0)))

    @property
    def sigma_heading(self) -> np.ndarray:
        """Heading standard deviation per robot (rad)."""
        return cast(np.ndarray, np.sqrt(np.maximum(self.cov[:, 2, 2], 0.0)))

    def select(self, mask: np.ndarray) -> SwarmEstimate:
        """The estimate of the robots where ``mask`` (n,) is True (the joint covariance marginalised to them)."""
        joint = None
        if self.joint is not None:
            idx = (3 * np.arange(self.n)[mask])[:, None] + np.arange(3)
            joint = self.joint[idx.ravel()[:, None], idx.ravel()[None, :]]
        return SwarmEstimate(self.ids[mask], self.poses[mask], self.cov[mask], joint)

    def with_subset(self, mask: np.ndarray, sub: SwarmEstimate) -> SwarmEstimate:
        """This estimate with the robots where ``mask`` (n,) replaced by ``sub`` (poses and covariances).

        The joint covariance is dropped (the cross-covariances of the two parts are unknown here).
        """
        poses, cov = self.poses.copy(), self.cov.copy()
        poses[mask], cov[mask] = sub.poses, sub.cov
        return SwarmEstimate(self.ids, poses, cov)


@dataclass(frozen=True)
class StepCommands:
    """Body-frame commands of one inchworm step: ``commands[i] = (turn rad, drive m)``.

    ``moving[i]`` is False for anchors, which stay still (their command is ignored).
    """

    ids: np.ndarray
    commands: np.ndarray
    moving: np.ndarray

    def __post_init__(self) -> None:
        ids = robot_ids(self.ids)
        commands = np.asarray(self.commands, dtype=float)
        moving = np.asarray(self.moving, dtype=bool)
        if commands.shape != (len(ids), 2) or moving.shape != (len(ids),):
            raise SwarmInputError(
                f"commands must be ({len(ids)}, 2) and moving ({len(ids)},), got {commands.shape} and {moving.shape}"
            )
        bad = _bad_rows(commands)
        if bad.size:
            raise SwarmInputError(f"commands hold NaN/inf for robots {ids[bad].tolist()}")
        if np.any(commands[:, 1] < 0):
            raise SwarmInputError(f"negative drive distance for robots {ids[commands[:, 1] < 0].tolist()}")
        commands = np.where(moving[:, None], commands, 0.0)
        object.__setattr__(self, "ids", ids)
        object.__setattr__(self, "commands", commands)
        object.__setattr__(self, "moving", moving)

    def select(self, mask: np.ndarray) -> StepCommands:
        """The commands of the robots where ``mask`` (n,) is True."""
        return StepCommands(self.ids[mask], self.commands[mask], self.moving[mask])

    @classmethod
    def stationary(cls, ids: np.ndarray | list[int]) -> StepCommands:
        """A step in which nobody moves (e.g. localizing from scratch)."""
        n = len(ids)
        return cls(np.asarray(ids), np.zeros((n, 2)), np.zeros(n, bool))


@dataclass(frozen=True)
class Observations:
    """Range/bearing observations (Eq. 20): ``observer`` saw ``observed`` at ``range_m``, ``bearing_rad``."""

    observer: np.ndarray
    observed: np.ndarray
    range_m: np.ndarray
    bearing_rad: np.ndarray

    def __post_init__(self) -> None:
        observer = np.asarray(self.observer).astype(np.int64)
        observed = np.asarray(self.observed).astype(np.int64)
        rng = np.asarray(self.range_m, dtype=float)
        brg = np.asarray(self.bearing_rad, dtype=float)
        m = len(observer)
        if not (observer.shape == observed.shape == rng.shape == brg.shape == (m,)):
            raise SwarmInputError("observation arrays must be 1-D and of equal length")
        bad = np.flatnonzero(~(np.isfinite(rng) & np.isfinite(brg)))
        if bad.size:
            pairs = [(int(observer[k]), int(observed[k])) for k in bad[:10]]
            raise SwarmInputError(f"observations hold NaN/inf (observer, observed): {pairs}")
        neg = np.flatnonzero(rng < 0)
        if neg.size:
            pairs = [(int(observer[k]), int(observed[k])) for k in neg[:10]]
            raise SwarmInputError(f"negative ranges in observations (observer, observed): {pairs}")
        selfobs = observer == observed
        if np.any(selfobs):
            raise SwarmInputError(f"robots observing themselves: {sorted(set(observer[selfobs].tolist()))}")
        object.__setattr__(self, "observer", observer)
        object.__setattr__(self, "observed", observed)
        object.__setattr__(self, "range_m", rng)
        object.__setattr__(self, "bearing_rad", brg)

    @classmethod
    def from_rows(cls, rows: np.ndarray | list[Any]) -> Observations:
        """From rows ``[observer, observed, range_m, bearing_rad]``."""
        arr = np.asarray(rows, dtype=float).reshape(-1, 4)
        ids = arr[:, :2]
        if np.any(~np.isfinite(ids)) or np.any(ids != np.round(ids)):
            raise SwarmInputError("observer/observed ids in observation rows must be integers")
        return cls(ids[:, 0].astype(np.int64), ids[:, 1].astype(np.int64), arr[:, 2], arr[:, 3])

    @classmethod
    def empty(cls) -> Observations:
        return cls(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0), np.zeros(0))

    def __len__(self) -> int:
        return len(self.observer)

    def select(self, mask: np.ndarray) -> Observations:
        """The rows where ``mask`` (one per observation) is True."""
        return Observations(self.observer[mask], self.observed[mask], self.range_m[mask], self.bearing_rad[mask])

    def indexed(self, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(observer index, observed index) into ``ids``; unknown ids raise naming them."""
        both = index_of(ids, np.concatenate([self.observer, self.observed]), "observations")
        return both[: len(self.observer)], both[len(self.observer) :]
