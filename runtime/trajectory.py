"""Point-to-point trajectories (Fig. 1): an initial swarm pose and a list of desired configurations.

File format (JSON, SI units; documented in docs/trajectory.md)::

    {"robots": [0, 1, 2],
     "initial_poses": [[x, y, heading], ...],          # one per robot: where the swarm starts
     "configurations": [[[x, y], ...], ...]}            # C_d1..C_dn_d, numbered from 1 in messages

A trajectory is feasible for localization only if every configuration keeps every
robot within sensing range of another robot and the sensing graph connected
(Section 5); ``validate_connected`` names the configuration and robots that are not.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from runtime.errors import SwarmInputError
from runtime.state import robot_ids


@dataclass(frozen=True)
class Trajectory:
    """``initial_poses`` (n, 3) and ``configurations`` (n_d, n, 2), ordered like ``ids``."""

    ids: np.ndarray
    initial_poses: np.ndarray
    configurations: np.ndarray

    def __post_init__(self) -> None:
        ids = robot_ids(self.ids)
        poses = np.asarray(self.initial_poses, dtype=float)
        configs = np.asarray(self.configurations, dtype=float)
        n = len(ids)
        if n < 2:
            raise SwarmInputError("a swarm trajectory needs at least 2 robots")
        if poses.shape != (n, 3):
            raise SwarmInputError(f"initial_poses must be {n} rows of [x, y, heading], got shape {poses.shape}")
        if configs.ndim != 3 or configs.shape[1:] != (n, 2) or configs.shape[0] < 1:
            raise SwarmInputError(f"configurations must be a non-empty list of {n} [x, y] rows each, got shape {configs.shape}")
        if not np.all(np.isfinite(poses)):
            raise SwarmInputError(f"initial_poses hold NaN/inf for robots {ids[~np.all(np.isfinite(poses), axis=1)].tolist()}")
        bad = ~np.all(np.isfinite(configs), axis=2)
        if bad.any():
            k = int(np.argmax(bad.any(axis=1)))
            raise SwarmInputError(f"configuration {k + 1} holds NaN/inf for robots {ids[bad[k]].tolist()}")
        object.__setattr__(self, "ids", ids)
        object.__setattr__(self, "initial_poses", poses)
        object.__setattr__(self, "configurations", configs)

    @property
    def n(self) -> int:
        return len(self.ids)

    def to_json(self) -> dict:
        return {
            "robots": self.ids.tolist(),
            "initial_poses": self.initial_poses.tolist(),
            "configurations": self.configurations.tolist(),
        }

    @classmethod
    def from_json(cls, data: object) -> Trajectory:
        if not isinstance(data, dict) or not {"robots", "initial_poses", "configurations"} <= set(data):
            raise SwarmInputError("a trajectory is a JSON object with 'robots', 'initial_poses' and 'configurations'")
        try:
            return cls(np.asarray(data["robots"]), np.asarray(data["initial_poses"], float), np.asarray(data["configurations"], float))
        except (TypeError, ValueError) as exc:
            if isinstance(exc, SwarmInputError):
                raise
            raise SwarmInputError(f"trajectory values must be numbers in nested lists: {exc}") from None

    def save(self, path: Path) -> None:
        Path(path).write_text(json.dumps(self.to_json()))

    @classmethod
    def load(cls, path: Path) -> Trajectory:
        try:
            data = json.loads(Path(path).read_text())
        except json.JSONDecodeError as exc:
            raise SwarmInputError(f"{path} is not valid JSON: {exc}") from None
        return cls.from_json(data)


def sensing_groups(positions: np.ndarray, sensing_range: float) -> np.ndarray:
    """Connected-component label per robot of the graph 'within sensing range'."""
    d = np.linalg.norm(positions[:, None, :] - positions[None, :, :], axis=-1)
    adj = (d <= sensing_range) & ~np.eye(len(positions), dtype=bool)
    import scipy.sparse as sp  # noqa: PLC0415 - scipy only when connectivity is checked (cheap parsers)
    from scipy.sparse.csgraph import connected_components  # noqa: PLC0415

    return connected_components(sp.csr_matrix(adj), directed=False)[1]


def is_connected(positions: np.ndarray, sensing_range: float) -> bool:
    """True when every robot is within sensing range of another and the graph is connected."""
    return int(sensing_groups(positions, sensing_range).max()) == 0 and len(positions) > 1


def validate_connected(traj: Trajectory, sensing_range: float) -> None:
    """Raise ``SwarmInputError`` naming the first configuration that cannot be localized."""
    for k, config in enumerate([traj.initial_poses[:, :2], *traj.configurations]):
        labels = sensing_groups(config, sensing_range)
        if labels.max() > 0:
            outside = labels != np.argmax(np.bincount(labels))
            where = "the initial configuration" if k == 0 else f"configuration {k}"
            raise SwarmInputError(
                f"{where} is not connected within the sensing range {sensing_range} m: robots {traj.ids[outside].tolist()} are cut off"
            )


def random_configuration(n: int, rng: np.random.Generator, spacing: float, sensing_range: float) -> np.ndarray:
    """A connected random configuration (n, 2) around the origin with mean spacing ``spacing`` (m)."""
    side = math.sqrt(n) * spacing
    while True:
        xy = rng.uniform(-side / 2, side / 2, (n, 2))
        if is_connected(xy, sensing_range) and min_separation(xy) >= 0.25 * spacing:
            return xy


def min_separation(xy: np.ndarray) -> float:
    d = np.linalg.norm(xy[:, None] - xy[None], axis=-1)
    return float(np.min(d + np.eye(len(xy)) * 1e9))


def random_trajectory(
    n: int,
    n_configs: int,
    rng: np.random.Generator,
    *,
    sensing_range: float = 0.5,
    spacing: float = 0.2,
    step: float = 0.3,
    turn: float = math.radians(30.0),
    reshape: float = 0.06,
    margin: float = 0.9,
) -> Trajectory:
    """A random trajectory as in Section 7: pose and topology change at every configuration.

    Each desired configuration is the previous one moved rigidly (translation ``step``
    m in a random direction, rotation up to ``turn`` rad about its centroid) and
    reshaped (each robot displaced by N(0, ``reshape``) m); draws are repeated until the
    configuration is connected within ``margin`` x ``sensing_range`` (so that motion
    errors rarely break the sensing graph) and no two robots are closer than a quarter
    of ``spacing``. The swarm starts at a random configuration connected the same way.
    """
    reach = margin * sensing_range
    start = random_configuration(n, rng, spacing, reach)
    configs = []
    prev = start
    for _ in range(n_configs):
        while True:
            ang = rng.uniform(-math.pi, math.pi)
            rot = rng.uniform(-turn, turn)
            c = prev.mean(axis=0)
            r = np.array([[math.cos(rot), -math.sin(rot)], [math.sin(rot), math.cos(rot)]])
            nxt = (prev - c) @ r.T + c + step * np.array([math.cos(ang), math.sin(ang)]) + rng.normal(0, reshape, (n, 2))
            if is_connected(nxt, reach) and min_separation(nxt) >= 0.25 * spacing:
                break
        configs.append(nxt)
        prev = nxt
    headings = rng.uniform(-math.pi, math.pi, n)
    return Trajectory(np.arange(n), np.column_stack([start, headings]), np.array(configs))
