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
from typing import Any

import numpy as np

from runtime.errors import OptionError, OutputError, SwarmInputError
from runtime.models.bodies import check_apart, impassable_pairs
from runtime.models.config import ModelConfig
from runtime.models.graph import component_labels
from runtime.models.state import robot_ids
from runtime.paths import StrPath


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

    def to_json(self) -> dict[str, Any]:
        return {
            "robots": self.ids.tolist(),
            "initial_poses": self.initial_poses.tolist(),
            "configurations": self.configurations.tolist(),
        }

    @classmethod
    def from_json(cls, data: object) -> Trajectory:
        """The trajectory of a JSON object (module doc); a malformed row is named (``configuration 2, row 4 (robot 3)``)."""
        if not isinstance(data, dict) or not {"robots", "initial_poses", "configurations"} <= set(data):
            raise SwarmInputError("a trajectory is a JSON object with 'robots', 'initial_poses' and 'configurations'")
        robots, poses, configs = data["robots"], data["initial_poses"], data["configurations"]
        if not isinstance(robots, list) or not all(isinstance(r, int) and not isinstance(r, bool) for r in robots):
            raise SwarmInputError(f"'robots' must be a list of integer robot ids, got {_short(robots)}")
        if not isinstance(configs, list) or not configs:
            raise SwarmInputError(f"'configurations' must be a non-empty list of configurations, got {_short(configs)}")
        table = _table(poses, 3, "initial_poses", "[x, y, heading]", robots)
        rows = [_table(c, 2, f"configuration {k + 1}", "[x, y]", robots) for k, c in enumerate(configs)]
        return cls(np.asarray(robots), table, np.stack(rows))

    def describe(self, sensing_range: float) -> dict[str, float]:
        """Robots, configurations and the robots' motion per configuration (mean and max, m); ``sensing_range`` (m) as given."""
        path = np.concatenate([self.initial_poses[None, :, :2], self.configurations])
        moves = np.linalg.norm(np.diff(path, axis=0), axis=-1)
        return {"robots": self.n, "configs": len(self.configurations), "sensing_range_m": sensing_range,
                "move_mean_m": float(moves.mean()), "move_max_m": float(moves.max())}

    def save(self, path: StrPath) -> None:
        """Write the trajectory as JSON to ``path``; ``OutputError`` naming the file if it cannot be written."""
        try:
            Path(path).write_text(json.dumps(self.to_json()))
        except OSError as exc:
            raise OutputError(f"cannot write the trajectory {path}: {exc.strerror or exc}") from None

    @classmethod
    def load(cls, path: StrPath) -> Trajectory:
        """The trajectory in the JSON file ``path``; ``SwarmInputError`` naming the file and what is wrong."""
        try:
            data = json.loads(Path(path).read_text())
        except OSError as exc:
            raise SwarmInputError(f"{path}: cannot read it: {exc.strerror or exc}") from None
        except json.JSONDecodeError as exc:
            raise SwarmInputError(f"{path} is not valid JSON: {exc}") from None
        except UnicodeDecodeError:
            raise SwarmInputError(f"{path} is not a text (JSON) file") from None
        try:
            return cls.from_json(data)
        except SwarmInputError as exc:
            raise SwarmInputError(f"trajectory {path}: {exc}") from None


def _short(value: object, limit: int = 60) -> str:
    text = json.dumps(value) if not isinstance(value, str) else repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _table(rows: object, width: int, what: str, shape: str, robots: list[int]) -> np.ndarray:
    """``rows`` as an (n, ``width``) float array, one row per robot; ``SwarmInputError`` naming the first bad row
    (1-based, with its robot id) and what it holds. The whole table is converted at once; rows are walked only
    to name the fault."""
    n = len(robots)
    if not isinstance(rows, list):
        raise SwarmInputError(f"{what} must be a list of {n} rows {shape}, got {_short(rows)}")
    with np.errstate(all="ignore"):
        try:
            table = np.asarray(rows, dtype=float)
            if table.shape == (n, width):
                return table
        except (TypeError, ValueError):
            pass
    for i, row in enumerate(rows):
        robot = f" (robot {robots[i]})" if i < n else ""
        if not isinstance(row, list) or len(row) != width:
            raise SwarmInputError(f"{what}, row {i + 1}{robot}: expected {shape}, got {_short(row)}")
        for v in row:
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise SwarmInputError(f"{what}, row {i + 1}{robot}: {_short(v)} is not a number")
    raise SwarmInputError(f"{what} must be {n} rows of {shape} (one per robot), got {len(rows)}")


def sensing_groups(positions: np.ndarray, sensing_range: float) -> np.ndarray:
    """Connected-component label per robot of the graph 'within sensing range' (0, 1, ... by lowest robot index).

    Pairs come from a k-d tree (O(n) pairs, not n^2); labels by ``runtime.models.graph.component_labels``.
    """
    from scipy.spatial import cKDTree  # noqa: PLC0415 - scipy only when connectivity is checked (cheap parsers)

    pairs = cKDTree(positions).query_pairs(sensing_range, output_type="ndarray") if len(positions) else np.zeros((0, 2), int)
    return component_labels(len(positions), pairs[:, 0], pairs[:, 1])


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


def validate_passable(traj: Trajectory, cfg: ModelConfig) -> None:
    """Raise ``SwarmInputError`` when robots' bodies overlap in a configuration of ``traj``,
    or when two robots cannot make a configuration change without touching in any order (``impassable_pairs``,
    e.g. a swap of places in a tight spot), naming the configuration and the robots. Exact geometry, no margin."""
    radius = cfg.robot_radius_m
    if radius <= 0:
        return
    configs = [traj.initial_poses[:, :2], *traj.configurations]
    for k, xy in enumerate(configs):
        check_apart(xy, traj.ids, radius, "the initial configuration" if k == 0 else f"configuration {k}")
    for k in range(1, len(configs)):
        pairs = impassable_pairs(configs[k - 1], configs[k], radius)
        if len(pairs):
            a, b = traj.ids[pairs[0]]
            raise SwarmInputError(
                f"configuration {k}: robots {a} and {b} cannot reach it without touching (bodies of radius {radius:g} m): "
                f"one first, the other first or both together, their centres come closer than {2 * radius:g} m; "
                f"give them room to pass (or robot radius 0: point robots)"
            )


def random_configuration(n: int, rng: np.random.Generator, spacing: float, sensing_range: float,
                         separation: float | None = None) -> np.ndarray:
    """A connected random configuration (n, 2) in a square of side sqrt(n) ``spacing`` (m) about the origin.

    Grown one robot at a time: each new robot is placed at a random distance in
    [sep, ``sensing_range``] from a random robot already placed (area-uniform
    in that annulus) and kept if it lies in the square and no closer than sep
    to every other robot, so the cloud is connected by construction and no draw is
    rejected as a whole (each draw checked against the robots of the nearest cells of a grid of side sep). sep = ``separation``
    (m), by default ``spacing`` / 4.
    """
    sep = MIN_SEPARATION * spacing if separation is None else separation
    _check_random_options(n, 1, spacing, sensing_range, sep)
    half = math.sqrt(n) * spacing / 2
    xy = np.empty((n, 2))
    xy[0] = rng.uniform(-half, half, 2)
    points = [(float(xy[0, 0]), float(xy[0, 1]))]  # plain floats: the loop runs ~10 draws a robot
    cells: dict[tuple[int, int], list[int]] = {(math.floor(points[0][0] / sep), math.floor(points[0][1] / sep)): [0]}  # by cell of side sep
    sep2, tries = sep**2, 0
    while len(points) < n:
        tries += 1
        if tries > 1000 * n:  # cannot happen with the checked options (the square holds ~16x more); never loop forever
            raise SwarmInputError(f"could not place {n} robots {sep} m apart within {sensing_range} m of one another")
        px, py = points[int(rng.integers(len(points)))]
        r, a = math.sqrt(rng.uniform(sep2, sensing_range**2)), rng.uniform(-math.pi, math.pi)
        x, y = px + r * math.cos(a), py + r * math.sin(a)
        if abs(x) > half or abs(y) > half:
            continue
        cx, cy = math.floor(x / sep), math.floor(y / sep)
        near = (points[k] for dx in (-1, 0, 1) for dy in (-1, 0, 1) for k in cells.get((cx + dx, cy + dy), ()))  # all within sep
        if all((qx - x) ** 2 + (qy - y) ** 2 >= sep2 for qx, qy in near):
            cells.setdefault((cx, cy), []).append(len(points))
            points.append((x, y))
    xy[:] = points
    return xy


MIN_SEPARATION = 0.25  # of the spacing: no two robots of a random configuration are closer


def min_separation(xy: np.ndarray) -> float:
    """The smallest distance between two robots of ``xy`` (n, 2), in m."""
    from scipy.spatial import cKDTree  # noqa: PLC0415 - scipy only when generating (cheap parsers)
    d, _ = cKDTree(xy).query(xy, k=2)
    return float(d[:, 1].min())


def _check_random_options(n: int, n_configs: int, spacing: float, reach: float, sep: float, **moves: float) -> None:
    """Up front, naming the option each value comes from (``OptionError``): sizes, and a range that can connect robots kept apart."""
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 2:
        raise OptionError("robots", f"must be >= 2 for a random trajectory, got {n}")
    if isinstance(n_configs, bool) or not isinstance(n_configs, (int, np.integer)) or n_configs < 1:
        raise OptionError("configs", f"must be >= 1 for a random trajectory, got {n_configs}")
    for name, value in {"spacing": spacing, **moves}.items():
        if not math.isfinite(value) or value < 0 or (name == "spacing" and value == 0):
            raise SwarmInputError(f"random trajectory {name} must be a finite number > 0, got {value}")
    if not reach > sep:
        raise OptionError("sensing_range", f"is too small for a random trajectory: robots are kept {sep:g} m apart and each must "
                          f"be within {reach:g} m of another; use a sensing range above {sep / RANGE_MARGIN:g} m")


END_SIGMAS = 3.0  # random configurations with bodies keep this many sigma of end-of-path error between them


def body_spacing(cfg: ModelConfig) -> dict[str, float]:
    """``random_trajectory``'s body options for a model: its robot radius and its larger motion noise
    (turn sigma in rad, or drive sigma as a fraction: the lateral or the along-track error per metre driven)."""
    return {"robot_radius": cfg.robot_radius_m, "motion_sigma": max(cfg.turn_sigma_rad, cfg.drive_sigma_frac)}


RANGE_MARGIN = 0.9  # random configurations are connected within this fraction of the sensing range


def _spanning_edges(xy: np.ndarray, reach: float) -> np.ndarray:
    """(m, 2) robot pairs of a minimum spanning forest of the graph 'within ``reach``' of ``xy``."""
    from scipy.sparse.csgraph import minimum_spanning_tree  # noqa: PLC0415
    from scipy.spatial import cKDTree  # noqa: PLC0415 - scipy only when generating (cheap parsers)
    mst = minimum_spanning_tree(cKDTree(xy).sparse_distance_matrix(cKDTree(xy), reach, output_type="coo_matrix").tocsr())
    return np.column_stack(mst.nonzero())


def _reshape(rigid: np.ndarray, noise: np.ndarray, edges: np.ndarray, reach: float, sep: float,
             prev: np.ndarray | None = None, radius: float = 0.0) -> np.ndarray:
    """``rigid`` + ``noise``, with the noise of robots that would break the configuration halved until none does.

    ``rigid`` is connected along ``edges`` within ``reach`` and keeps robots ``sep`` apart, so
    halving converges to it in the worst case. A robot breaks the configuration when it is
    closer than ``sep`` to another, or when it ends a spanning edge of ``rigid`` that now joins
    two parts of the graph 'within ``reach``' (there is one while the graph is cut), or, with
    bodies of ``radius`` > 0, when it and another cannot both come from ``prev`` without
    touching in any order (``runtime.models.bodies.impassable_pairs``; a rigid motion of robots
    ``sep`` > 2 ``radius`` apart turning by at most 30 degrees never has such a pair).
    """
    from scipy.sparse.csgraph import connected_components  # noqa: PLC0415
    from scipy.spatial import cKDTree  # noqa: PLC0415 - scipy only when generating (cheap parsers)
    scale = np.ones(len(rigid))
    for _ in range(60):
        xy: np.ndarray = rigid + scale[:, None] * noise
        tree = cKDTree(xy)
        bad = tree.query_pairs(sep, output_type="ndarray").ravel()
        if not len(bad) and radius > 0 and prev is not None:
            bad = impassable_pairs(prev, xy, radius).ravel()
        if not len(bad):  # the (costlier) connectivity check only once robots are apart
            parts, label = connected_components(tree.sparse_distance_matrix(tree, reach, output_type="coo_matrix"), directed=False)
            if parts == 1:
                return xy
            bad = edges[label[edges[:, 0]] != label[edges[:, 1]]].ravel()
        scale[bad] *= 0.5
    return rigid


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
    margin: float = RANGE_MARGIN,
    robot_radius: float = 0.0,
    motion_sigma: float = 0.0,
) -> Trajectory:
    """A random trajectory as in Section 7: pose and topology change at every configuration.

    The swarm starts at a random configuration (``random_configuration``) connected within
    ``margin`` x ``sensing_range`` (so that motion errors rarely break the sensing graph).
    Each desired configuration is the previous one moved rigidly (translation ``step`` m
    in a random direction, rotation up to ``turn`` rad about its centroid, and at most
    the angle that moves the farthest robot by ``step`` m, so that a large swarm's edge
    does not swing by metres, beyond what one robot drives in a step) and reshaped
    (each robot displaced by N(0, ``reshape``) m); a robot whose displacement would cut the
    graph within ``margin`` x ``sensing_range`` or bring it closer than a quarter of
    ``spacing`` to another has its displacement halved until none does (no redrawing, so
    1000 robots take well under a second). Deterministic for a given ``rng`` state.
    Raises ``SwarmInputError`` naming the option for sizes below 2 robots / 1
    configuration or a sensing range too small for robots kept apart. With ``robot_radius`` > 0
    (m) robots are kept at least 2 ``robot_radius`` + 3 sqrt(2) ``step`` ``motion_sigma`` apart
    (bodies, plus three standard deviations of two robots' relative end-of-path error after a
    drive of ``step`` with relative motion noise ``motion_sigma``, see ``body_spacing``), but no
    more than half the ``spacing`` unless the bodies need it, and every
    change can be made without bodies touching (``validate_passable``);
    ``robot_radius`` 0 draws exactly as before bodies.
    """
    reach = margin * sensing_range
    sep = MIN_SEPARATION * spacing
    if robot_radius > 0:  # room for the end-of-path error, but at most half the spacing (the swarm keeps its density)
        sep = max(sep, 2.0 * robot_radius, min(2.0 * robot_radius + END_SIGMAS * math.sqrt(2.0) * step * motion_sigma, spacing / 2))
    _check_random_options(n, n_configs, spacing, reach, sep, step=step, turn=turn, reshape=reshape)
    if not 0 < margin <= 1:
        raise SwarmInputError(f"random trajectory margin must be in (0, 1], got {margin}")
    start = random_configuration(n, rng, spacing, reach, sep)
    configs = []
    prev = start
    for _ in range(n_configs):
        ang = rng.uniform(-math.pi, math.pi)
        c = prev.mean(axis=0)
        swing = min(turn, step / max(float(np.max(np.linalg.norm(prev - c, axis=1))), 1e-9))
        rot = rng.uniform(-swing, swing)
        r = np.array([[math.cos(rot), -math.sin(rot)], [math.sin(rot), math.cos(rot)]])
        rigid = (prev - c) @ r.T + c + step * np.array([math.cos(ang), math.sin(ang)])
        nxt = _reshape(rigid, rng.normal(0, reshape, (n, 2)), _spanning_edges(rigid, reach), reach, sep, prev, robot_radius)
        configs.append(nxt)
        prev = nxt
    headings = rng.uniform(-math.pi, math.pi, n)
    return Trajectory(np.arange(n), np.column_stack([start, headings]), np.array(configs))
