"""The ROS 2 driver's settings, velocity profiles and sensing windows: the parts that need no ROS 2 (docs/ros2.md).

``Ros2Config.load(options)`` reads ``--driver-option config=FILE`` (TOML) and then the other
``--driver-option KEY=VALUE`` pairs, each naming a key of a section below, which override the file:

    namespace = "/robot{id}"          # per robot ({id}: its id); [namespaces] overrides single robots
    frame = "robot{id}/base_link"     # the body frame of sightings (header.frame_id / child_frame_id)
    [topics]   cmd_vel = "cmd_vel"  odom = "odom"  neighbors = "neighbors"  ground_truth = ""   # relative to the namespace
    [limits]   max_linear_speed = 0.2  max_angular_speed = 1.0  linear_accel = 0.5  angular_accel = 2.0   # m/s, rad/s, /s
    [timing]   rate_hz = 20  silence_s = 1.0  sensing_window_s = 0.3  settle_s = 0.1  # cmd_vel rate; lost after; sightings; at rest
    [qos]      cmd_vel = "reliable"  depth = 10      # subscribers are best effort: they accept either kind of publisher
    [namespaces]  3 = "/tb3_3"

``velocity_profile`` is the trapezoid (triangle when short) that covers a distance within the speed and
acceleration limits, sampled at the command rate and scaled so its samples cover the distance exactly.
``SightingWindow`` keeps the ``neighbors`` sightings and makes one sensing window's observations of them.
"""

from __future__ import annotations

import math
import re
import tomllib
from collections import deque
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, cast

import numpy as np

from runtime.errors import OptionError, SwarmInputError
from runtime.models.geometry import wrap_angle

SECTIONS = {"topics": ("cmd_vel", "odom", "neighbors", "ground_truth"),
            "limits": ("max_linear_speed", "max_angular_speed", "linear_accel", "angular_accel"),
            "timing": ("rate_hz", "silence_s", "sensing_window_s", "settle_s"),
            "qos": ("cmd_vel_qos", "depth")}


@dataclass(frozen=True)
class Ros2Config:
    """How the driver finds and drives one robot (module doc); SI units."""

    namespace: str = "/robot{id}"
    frame: str = "robot{id}/base_link"
    cmd_vel: str = "cmd_vel"
    odom: str = "odom"
    neighbors: str = "neighbors"
    ground_truth: str = ""  # nav_msgs/Odometry of a tracker (or simulator) in the world frame; "" = none
    max_linear_speed: float = 0.2
    max_angular_speed: float = 1.0
    linear_accel: float = 0.5
    angular_accel: float = 2.0
    rate_hz: float = 20.0
    silence_s: float = 1.0
    sensing_window_s: float = 0.3
    settle_s: float = 0.1
    cmd_vel_qos: str = "reliable"
    depth: int = 10
    namespaces: dict[int, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for name in ("max_linear_speed", "max_angular_speed", "linear_accel", "angular_accel", "rate_hz", "silence_s",
                     "sensing_window_s"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise SwarmInputError(f"ROS 2 driver: {name} must be a number > 0, got {value!r}")
        if not (math.isfinite(self.settle_s) and self.settle_s >= 0):
            raise SwarmInputError(f"ROS 2 driver: settle_s must be >= 0, got {self.settle_s!r}")
        if self.cmd_vel_qos not in ("reliable", "best_effort"):
            raise SwarmInputError(f"ROS 2 driver: qos cmd_vel must be reliable or best_effort, got {self.cmd_vel_qos!r}")
        if self.depth < 1:
            raise SwarmInputError(f"ROS 2 driver: qos depth must be >= 1, got {self.depth!r}")
        if "{id}" not in self.frame:
            raise SwarmInputError(f"ROS 2 driver: frame must contain {{id}}, got {self.frame!r}")

    @classmethod
    def load(cls, options: dict[str, str] | None = None) -> Ros2Config:
        """The file of ``options["config"]`` (if any) with the other options on top; errors name the key."""
        options = dict(options or {})
        values: dict[str, object] = {}
        path = options.pop("config", None)
        if path:
            try:
                data = tomllib.loads(Path(path).expanduser().read_text(encoding="utf-8"))
            except OSError as exc:
                raise OptionError("driver_option", f"config={path}: cannot read it: {exc.strerror or exc}") from None
            except tomllib.TOMLDecodeError as exc:
                raise OptionError("driver_option", f"config={path}: not TOML: {exc}") from None
            values = _flatten(data, path)
        known = {f.name: f for f in fields(cls)}
        for key, text in options.items():
            name = "cmd_vel_qos" if key == "qos.cmd_vel" else key.rpartition(".")[2]
            if name not in known or name == "namespaces":
                raise OptionError("driver_option", f"{key}: not a setting of the ROS 2 driver ({', '.join(sorted(known))})")
            values[name] = _parse(text, known[name].type, key)
        try:
            return cls(**values)  # type: ignore[arg-type]
        except TypeError as exc:
            raise SwarmInputError(f"ROS 2 driver settings: {exc}") from None

    def namespace_of(self, robot: int) -> str:
        return self.namespaces.get(int(robot), self.namespace).replace("{id}", str(int(robot)))

    def frame_of(self, robot: int) -> str:
        return self.frame.replace("{id}", str(int(robot)))

    def motion_time_s(self, turn_rad: float, drive_m: float) -> float:
        """How long the driver takes to execute (turn, drive): both profiles at ``rate_hz``, then ``settle_s``."""
        dt = 1.0 / self.rate_hz
        steps = len(velocity_profile(turn_rad, self.max_angular_speed, self.angular_accel, dt))
        return (steps + len(velocity_profile(drive_m, self.max_linear_speed, self.linear_accel, dt))) * dt + self.settle_s


def _flatten(data: dict[str, Any], path: str) -> dict[str, object]:
    out: dict[str, object] = {}
    for key, value in data.items():
        if key == "namespaces":
            if not isinstance(value, dict):
                raise OptionError("driver_option", f"config={path}: [namespaces] must map robot ids to namespaces")
            try:
                out["namespaces"] = {int(k): str(v) for k, v in value.items()}
            except ValueError:
                raise OptionError("driver_option", f"config={path}: [namespaces] keys must be robot ids, got {list(value)}") from None
        elif key in SECTIONS:
            if not isinstance(value, dict):
                raise OptionError("driver_option", f"config={path}: {key} must be a table [{key}]")
            for name, item in value.items():
                if name not in SECTIONS[key] and not (key == "qos" and name == "cmd_vel"):
                    raise OptionError("driver_option", f"config={path}: [{key}] has no setting {name!r} ({', '.join(SECTIONS[key])})")
                out["cmd_vel_qos" if key == "qos" and name == "cmd_vel" else name] = item
        elif key in ("namespace", "frame"):
            out[key] = str(value)
        else:
            raise OptionError("driver_option", f"config={path}: unknown key {key!r} (namespace, frame, [{'], ['.join(SECTIONS)}], [namespaces])")
    return out


def _parse(text: str, kind: object, key: str) -> object:
    if kind in ("float", float):
        try:
            return float(text)
        except ValueError:
            raise OptionError("driver_option", f"{key}={text}: not a number") from None
    if kind in ("int", int):
        try:
            return int(text)
        except ValueError:
            raise OptionError("driver_option", f"{key}={text}: not an integer") from None
    return text


def velocity_profile(distance: float, vmax: float, amax: float, dt: float) -> np.ndarray:
    """Signed speeds, one per ``dt``, that cover ``distance`` with |v| <= vmax and |dv/dt| <= amax (trapezoid,
    or triangle when short), sampled at the middle of each period and scaled to cover ``distance`` exactly."""
    d = abs(float(distance))
    if d == 0.0:
        return np.zeros(0)
    ramp = vmax / amax  # time to full speed
    if amax * ramp * ramp >= d:  # never reaches vmax: triangle
        ramp = math.sqrt(d / amax)
        cruise, peak = 0.0, amax * ramp
    else:
        cruise, peak = (d - amax * ramp * ramp) / vmax, vmax
    total = 2 * ramp + cruise
    t = (np.arange(max(1, math.ceil(total / dt))) + 0.5) * dt
    v = np.minimum.reduce([np.full_like(t, peak), amax * t, amax * np.maximum(total - t, 0.0) + 1e-12])
    v *= d / (v.sum() * dt)  # exact coverage at the sampling rate
    return cast(np.ndarray, math.copysign(1.0, distance) * v)


def closed_loop_speed(remaining: float, elapsed: float, vmax: float, amax: float, dt: float) -> float:
    """The speed (>= 0) for the next ``dt`` towards a target ``remaining`` away (negative: passed), ``elapsed`` s into the
    motion: ramped up at ``amax``, capped at ``vmax``, braking so it could stop at the target (sqrt(2 a d)), at least
    ``amax * dt`` (so it arrives) but never past the target in one period; 0 once there (within 1 % of a crawl's period)."""
    crawl = amax * dt
    if remaining <= crawl * dt * 0.01:
        return 0.0
    return min(max(crawl, min(vmax, amax * (elapsed + dt), math.sqrt(2.0 * amax * remaining))), remaining / dt)


class SightingWindow:
    """The ``neighbors`` sightings of robot ``robot`` (of the run ``ids``) as they arrive, and one window's observations.

    A sighting counts for a window that opened at ``since_ns`` when its header stamp is at or after ``since_ns``
    (one taken earlier, while robots moved, that arrives late is dropped), its frame is this robot's and its child
    another robot of the run; of several sightings of the same robot (a sensor's repeated frames, duplicates) the
    newest counts, once. Bad sightings are counted in ``dropped`` by reason.
    """

    def __init__(self, robot: int, ids: tuple[int, ...] | list[int], frame_pattern: str, keep: int = 4096) -> None:
        self.robot = int(robot)
        self.ids = frozenset(int(i) for i in ids)
        self.own_frame = frame_pattern.replace("{id}", str(self.robot))
        self._child = re.compile("^" + re.escape(frame_pattern).replace(re.escape("{id}"), r"(\d+)") + "$")
        self._seen: deque[tuple[int, int, float, float]] = deque(maxlen=keep)  # (stamp ns, robot, x, y)
        self.dropped: dict[str, int] = {}

    def _drop(self, why: str) -> None:
        self.dropped[why] = self.dropped.get(why, 0) + 1

    def add(self, stamp_ns: int, frame_id: str, child_frame_id: str, x: float, y: float) -> None:
        """One sighting: ``child_frame_id``'s robot at (x, y) in ``frame_id`` (the observer's body frame)."""
        if frame_id.lstrip("/") != self.own_frame.lstrip("/"):
            return self._drop("another observer's frame")
        match = self._child.match(child_frame_id.lstrip("/"))
        if match is None:
            return self._drop("child frame of no robot")
        other = int(match[1])
        if other == self.robot or other not in self.ids:
            return self._drop("itself" if other == self.robot else "a robot not in the run")
        if not (math.isfinite(x) and math.isfinite(y)):
            return self._drop("not finite")
        self._seen.append((int(stamp_ns), other, float(x), float(y)))
        return None

    def observations(self, since_ns: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(ids ascending, ranges m, bearings rad in [-pi, pi)) of the newest sighting of each robot since ``since_ns``."""
        newest: dict[int, tuple[int, float, float]] = {}
        for t, other, x, y in list(self._seen):
            if t < since_ns:
                continue
            if other not in newest or t >= newest[other][0]:
                newest[other] = (t, x, y)
        ids = np.array(sorted(newest), dtype=np.int64)
        xy = np.array([newest[int(i)][1:] for i in ids], dtype=float).reshape(len(ids), 2)
        return ids, np.hypot(xy[:, 0], xy[:, 1]), wrap_angle(np.arctan2(xy[:, 1], xy[:, 0]))
