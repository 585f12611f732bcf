"""The gateway config file (docs/gateway.md): ports, the robots behind each, calibration, timing, limits.

A JSON object (example: ``deploy/gateway.example.json``)::

    {
      "ports": [{"name": "radio0", "device": "/dev/ttyUSB0", "baud": 115200, "transport": "serial",
                 "robots": [0, 1, 2]}],
      "calibration": {"1": {"range_bias_m": 0.01, "bearing_offset_rad": -0.02, "motion_scale": 0.97}},
      "timing": {"ack_timeout_s": 0.1, "max_retries": 5, ...},
      "limits": {"max_drive_m": 0.3, "max_turn_rad": 3.1416, "workspace": [-1, -1, 3, 3], "robot_radius_m": 0.011}
    }

Only ``ports`` is required. ``GatewayConfig.load`` validates everything and raises
``SwarmInputError`` naming the file, the field and what is wrong. Units are SI (m, rad, s).
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Mapping, Set as AbstractSet
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from runtime.errors import SwarmInputError
from runtime.models.geometry import wrap_angle
from runtime.paths import StrPath
from runtime.wire.keys import KeyspaceError, validate_port

TRANSPORTS = ("serial", "ant")
MAX_LINK_ROBOT = 0xFFFE  # robot ids fit the frame's u16 ROBOT field (0xFFFF is broadcast)


@dataclass(frozen=True)
class Calibration:
    """How robot ``r``'s sensors and motion deviate; the gateway agent corrects for them.

    Measured range = true + ``range_bias_m``; measured bearing = true + ``bearing_offset_rad``;
    driven distance = commanded x ``motion_scale`` (``driven``, ``measured_*``: the deviation,
    as the robot emulator applies it). The agent sends drive / motion_scale and reports
    range - bias and bearing - offset, wrapped to [-pi, pi] (``corrected_*``: its inverse).
    """

    range_bias_m: float = 0.0
    bearing_offset_rad: float = 0.0
    motion_scale: float = 1.0

    def driven(self, drive_m: float) -> float:
        return drive_m * self.motion_scale

    def measured_ranges(self, ranges_m: np.ndarray) -> np.ndarray:
        """The ranges the robot reports for true ``ranges_m`` (unchanged, bit for bit, without a bias)."""
        return np.maximum(ranges_m + self.range_bias_m, 0.0) if self.range_bias_m else ranges_m

    def measured_bearings(self, bearings_rad: np.ndarray) -> np.ndarray:
        """The bearings the robot reports for true ``bearings_rad`` (unchanged without an offset)."""
        return wrap_angle(bearings_rad + self.bearing_offset_rad) if self.bearing_offset_rad else bearings_rad

    def corrected_drive(self, drive_m: float) -> float:
        return drive_m / self.motion_scale

    def corrected_range(self, range_m: float) -> float:
        return max(range_m - self.range_bias_m, 0.0)

    def corrected_bearing(self, bearing_rad: float) -> float:
        return math.remainder(bearing_rad - self.bearing_offset_rad, 2 * math.pi)


STEP_TIMEOUT_S = 5.0  # the coordinator's default --step-timeout (coordinator.node.zenoh_backend.Timeouts.step_s)
DRIVER_MARGIN_S = 0.2  # the agent re-sends a request the link said nothing about for retry_budget_s + this


@dataclass(frozen=True)
class Timing:
    """Link timing (s): docs/gateway-protocol.md, Reliability.

    One budget drives every retry: ``retry_budget_s`` = ``ack_timeout_s`` x (``max_retries`` + 1),
    how long the link retransmits a request (every ``ack_timeout_s``, also after ACCEPTED)
    to a robot that says nothing before reporting it lost. The gateway driver re-sends a
    request after ``resend_s`` and gives up after ``answer_timeout_s``; both derive from it
    and, for every request but a motion still answered ACCEPTED, stay below the coordinator's
    step timeout (``STEP_TIMEOUT_S``), so a lost robot is reported by id before the step times out.
    ``motion_timeout_s`` is the longest motion a robot may take (it keeps answering ACCEPTED).
    """

    ack_timeout_s: float = 0.1
    max_retries: int = 15
    motion_timeout_s: float = 4.0
    heartbeat_period_s: float = 0.1
    heartbeat_timeout_s: float = 2.0  # longer than retry_budget_s + ack_timeout_s: a blackout the link survives does not stop a motion
    robot_timeout_s: float = 2.0
    stats_period_s: float = 1.0

    @property
    def retry_budget_s(self) -> float:
        """Seconds the link keeps retransmitting to a silent robot before reporting it lost."""
        return self.ack_timeout_s * (self.max_retries + 1)

    @property
    def resend_s(self) -> float:
        """Seconds of silence from the link after which the gateway driver re-sends its request."""
        return self.retry_budget_s + DRIVER_MARGIN_S

    def answer_timeout_s(self, motion: bool) -> float:
        """Seconds the gateway driver waits for the link's final answer: two full link budgets
        (the request and one re-send), plus ``motion_timeout_s`` for a motion."""
        return 2 * self.resend_s + (self.motion_timeout_s if motion else 0.0)


@dataclass(frozen=True)
class Limits:
    """Safety limits every gateway agent checks before a byte is written.

    |turn| <= ``max_turn_rad``, 0 <= drive <= ``max_drive_m``, and the predicted end position
    (from the latest estimate) inside ``workspace`` = (x_min, y_min, x_max, y_max) in metres, if set.
    ``robot_radius_m``: the robots' body radius (m, docs/bodies.md); a run planned with another
    ``--robot-radius`` is refused before it starts.
    """

    max_drive_m: float = 0.5
    max_turn_rad: float = math.pi
    workspace: tuple[float, float, float, float] | None = None
    robot_radius_m: float = 0.011


@dataclass(frozen=True)
class Port:
    """One serial/radio port: its ``name`` (key chunk), ``device`` path, baud rate, transport and robots."""

    name: str
    device: str
    robots: tuple[int, ...]
    baud: int = 115200
    transport: str = "serial"


@dataclass(frozen=True)
class GatewayConfig:
    """Everything a gateway PC needs to know about its robots (see module doc)."""

    ports: tuple[Port, ...]
    calibration: Mapping[int, Calibration] = field(default_factory=dict)
    timing: Timing = Timing()
    limits: Limits = Limits()
    source: str = "<memory>"

    @property
    def robots(self) -> list[int]:
        return sorted(r for p in self.ports for r in p.robots)

    def port_of(self, robot: int) -> Port:
        """The port robot ``robot`` is behind; ``SwarmInputError`` if none."""
        for p in self.ports:
            if robot in p.robots:
                return p
        raise SwarmInputError(f"{self.source}: robot {robot} is behind no port (robots: {self.robots})")

    def port(self, name: str) -> Port:
        for p in self.ports:
            if p.name == name:
                return p
        raise SwarmInputError(f"{self.source}: no port named {name!r} (ports: {[p.name for p in self.ports]})")

    def calibration_of(self, robot: int) -> Calibration:
        return self.calibration.get(robot, Calibration())

    def with_devices(self, devices: Mapping[str, str]) -> GatewayConfig:
        """The same config with the device paths of the named ports replaced (e.g. by emulator ptys)."""
        ports = tuple(dataclasses.replace(p, device=devices.get(p.name, p.device)) for p in self.ports)
        return dataclasses.replace(self, ports=ports)

    def to_json(self) -> dict[str, Any]:
        return {
            "ports": [dataclasses.asdict(p) | {"robots": list(p.robots)} for p in self.ports],
            "calibration": {str(r): dataclasses.asdict(c) for r, c in sorted(self.calibration.items())},
            "timing": dataclasses.asdict(self.timing),
            "limits": dataclasses.asdict(self.limits) | {"workspace": None if self.limits.workspace is None else list(self.limits.workspace)},
        }

    def save(self, path: str | Path) -> None:
        Path(path).write_text(json.dumps(self.to_json(), indent=2) + "\n")

    @classmethod
    def load(cls, path: StrPath) -> GatewayConfig:
        """Read and validate a gateway config file."""
        try:
            text = Path(path).read_text()
        except OSError as exc:
            raise SwarmInputError(f"cannot read the gateway config {path}: {exc.strerror or exc}") from None
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise SwarmInputError(f"gateway config {path} is not valid JSON: {exc}") from None
        return cls.from_json(data, str(path))

    @classmethod
    def from_json(cls, data: Any, source: str = "<memory>") -> GatewayConfig:
        return _Parser(source).config(data)


class _Parser:
    """Validation with errors that name the file and the field."""

    def __init__(self, source: str) -> None:
        self.source = source

    def fail(self, where: str, problem: str) -> SwarmInputError:
        return SwarmInputError(f"gateway config {self.source}: {where}: {problem}")

    def obj(self, value: Any, where: str, allowed: set[str], required: AbstractSet[str] = frozenset()) -> dict[str, Any]:
        if not isinstance(value, dict):
            raise self.fail(where, f"must be an object, got {type(value).__name__}")
        unknown = sorted(set(value) - allowed)
        if unknown:
            raise self.fail(where, f"unknown field(s) {unknown} (allowed: {sorted(allowed)})")
        missing = sorted(required - set(value))
        if missing:
            raise self.fail(where, f"missing field(s) {missing}")
        return value

    def number(self, value: Any, where: str, *, positive: bool = False, nonneg: bool = False) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise self.fail(where, f"must be a finite number, got {value!r}")
        if positive and value <= 0:
            raise self.fail(where, f"must be > 0, got {value!r}")
        if nonneg and value < 0:
            raise self.fail(where, f"must be >= 0, got {value!r}")
        return float(value)

    def integer(self, value: Any, where: str, lo: int, hi: int) -> int:
        if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
            raise self.fail(where, f"must be an integer in [{lo}, {hi}], got {value!r}")
        return value

    def robot_id(self, value: Any, where: str) -> int:
        if isinstance(value, str) and value.isdigit():
            value = int(value)
        return self.integer(value, where, 0, MAX_LINK_ROBOT)

    def config(self, data: Any) -> GatewayConfig:
        data = self.obj(data, "top level", {"ports", "calibration", "timing", "limits"}, {"ports"})
        ports_raw = data["ports"]
        if not isinstance(ports_raw, list) or not ports_raw:
            raise self.fail("ports", "must be a non-empty list")
        ports = tuple(self.port(p, f"ports[{i}]") for i, p in enumerate(ports_raw))
        seen: dict[int, str] = {}
        names: set[str] = set()
        for p in ports:
            if p.name in names:
                raise self.fail("ports", f"two ports are named {p.name!r}")
            names.add(p.name)
            for r in p.robots:
                if r in seen:
                    raise self.fail("ports", f"robot {r} is behind both {seen[r]!r} and {p.name!r}")
                seen[r] = p.name
        calibration = {}
        cal = data.get("calibration", {})
        if not isinstance(cal, dict):
            raise self.fail("calibration", f"must be an object of robot id -> calibration, got {type(cal).__name__}")
        for key, value in cal.items():
            robot = self.robot_id(key, f"calibration key {key!r}")
            if robot not in seen:
                raise self.fail(f"calibration[{key!r}]", f"robot {robot} is behind no port")
            where = f"calibration[{key!r}]"
            c = self.obj(value, where, {f.name for f in dataclasses.fields(Calibration)})
            calibration[robot] = Calibration(
                range_bias_m=self.number(c.get("range_bias_m", 0.0), f"{where}.range_bias_m"),
                bearing_offset_rad=self.number(c.get("bearing_offset_rad", 0.0), f"{where}.bearing_offset_rad"),
                motion_scale=self.number(c.get("motion_scale", 1.0), f"{where}.motion_scale", positive=True),
            )
        return GatewayConfig(ports, calibration, self.timing(data.get("timing", {})), self.limits(data.get("limits", {})), self.source)

    def port(self, value: Any, where: str) -> Port:
        p = self.obj(value, where, {"name", "device", "robots", "baud", "transport"}, {"name", "device", "robots"})
        try:
            name = validate_port(p["name"])
        except KeyspaceError as exc:
            raise self.fail(f"{where}.name", str(exc)) from None
        if not isinstance(p["device"], str) or not p["device"]:
            raise self.fail(f"{where}.device", f"must be a device path (e.g. /dev/ttyUSB0), got {p['device']!r}")
        robots = p["robots"]
        if not isinstance(robots, list) or not robots:
            raise self.fail(f"{where}.robots", "must be a non-empty list of robot ids")
        ids = tuple(self.robot_id(r, f"{where}.robots[{i}]") for i, r in enumerate(robots))
        if len(set(ids)) != len(ids):
            raise self.fail(f"{where}.robots", "lists a robot twice")
        transport = p.get("transport", "serial")
        if transport not in TRANSPORTS:
            raise self.fail(f"{where}.transport", f"must be one of {TRANSPORTS}, got {transport!r}")
        baud = self.integer(p.get("baud", 115200), f"{where}.baud", 1, 10_000_000)
        return Port(name, p["device"], ids, baud, transport)

    def timing(self, value: Any) -> Timing:
        names = {f.name for f in dataclasses.fields(Timing)}
        t = self.obj(value, "timing", names)
        out: dict[str, Any] = {}  # max_retries an int, the rest floats
        for name in names & set(t):
            if name == "max_retries":
                out[name] = self.integer(t[name], "timing.max_retries", 0, 100)
            else:
                out[name] = self.number(t[name], f"timing.{name}", positive=True)
        timing = Timing(**out)
        if timing.answer_timeout_s(motion=False) >= STEP_TIMEOUT_S:
            raise self.fail("timing", f"ack_timeout_s x (max_retries + 1) = {timing.retry_budget_s:g} s is too long: the agent's "
                                      f"wait 2 x ({timing.retry_budget_s:g} + {DRIVER_MARGIN_S:g}) s must stay below the "
                                      f"coordinator's step timeout {STEP_TIMEOUT_S:g} s")
        if timing.robot_timeout_s >= STEP_TIMEOUT_S:
            raise self.fail("timing.robot_timeout_s", f"{timing.robot_timeout_s:g} s must stay below the coordinator's "
                                                      f"step timeout {STEP_TIMEOUT_S:g} s")
        if timing.heartbeat_period_s >= timing.heartbeat_timeout_s:
            raise self.fail("timing", f"heartbeat_period_s ({timing.heartbeat_period_s}) must be below heartbeat_timeout_s "
                                      f"({timing.heartbeat_timeout_s}), or robots stop between heartbeats")
        if timing.heartbeat_timeout_s <= timing.retry_budget_s + timing.ack_timeout_s:
            raise self.fail("timing", f"heartbeat_timeout_s ({timing.heartbeat_timeout_s:g}) must exceed the retry budget plus one "
                                      f"retransmission ({timing.retry_budget_s + timing.ack_timeout_s:g} s), or a radio blackout "
                                      f"the link survives stops a robot in the middle of its motion")
        return timing

    def limits(self, value: Any) -> Limits:
        lim = self.obj(value, "limits", {"max_drive_m", "max_turn_rad", "workspace", "robot_radius_m"})
        d = Limits()
        workspace = lim.get("workspace")
        if workspace is not None:
            if not isinstance(workspace, list) or len(workspace) != 4:
                raise self.fail("limits.workspace", f"must be [x_min, y_min, x_max, y_max] in metres, got {workspace!r}")
            workspace = tuple(self.number(v, f"limits.workspace[{i}]") for i, v in enumerate(workspace))
            if not (workspace[0] < workspace[2] and workspace[1] < workspace[3]):
                raise self.fail("limits.workspace", f"needs x_min < x_max and y_min < y_max, got {list(workspace)}")
        return Limits(
            max_drive_m=self.number(lim.get("max_drive_m", d.max_drive_m), "limits.max_drive_m", positive=True),
            max_turn_rad=self.number(lim.get("max_turn_rad", d.max_turn_rad), "limits.max_turn_rad", positive=True),
            robot_radius_m=self.number(lim.get("robot_radius_m", d.robot_radius_m), "limits.robot_radius_m", nonneg=True),
            workspace=workspace,
        )
