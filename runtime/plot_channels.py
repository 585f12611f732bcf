"""Plottable JSON channels of a run, derived from the raw msgpack messages (docs/recording.md).

Foxglove (Plot, Raw Message, State Transitions panels) and PlotJuggler read MCAP channels
whose message encoding is ``json`` and whose schema is a ``jsonschema``; they cannot decode
our msgpack. The recorder (``runtime.recording``) writes these channels next to the raw
ones, each message right after the raw one it comes from, with its ``stamp_ns`` as publish
time. Every field is a flat number (or, for plans and events, a short string or id list),
so a plot path is simply ``/robot/3/estimate.x``. Units SI: m, rad.

Topics and schemas (``SCHEMAS``):

* ``/robot/<id>/estimate`` (``inchworm.RobotEstimate``), per ``EstimateMessage``: the fused
  estimate ``x``, ``y``, ``heading`` and its standard deviations ``std_x``, ``std_y``,
  ``std_heading`` (square roots of the covariance diagonal), ``anchor`` (1 if the robot
  stood still in this step under the current plan, 0 if it moved, -1 unknown).
* ``/robot/<id>/truth`` (``inchworm.RobotTruth``), per ``TruthSetMessage`` (simulated runs):
  the true ``x``, ``y``, ``heading``.
* ``/robot/<id>/error`` (``inchworm.RobotError``), once the estimate and the truth of a step
  are both known: ``localization_m`` = |true - estimated position| (the per-robot term of
  e_l, Eq. 8), ``dx``, ``dy``, ``dheading`` (estimate - truth, heading wrapped to
  [-pi, pi)); with the desired configuration known (``PlanMessage`` + trajectory metadata)
  also ``following_m`` = |true - desired position| of the configuration the step heads for.
* ``/swarm/error`` (``inchworm.SwarmError``), the same step: ``localization_mean_m`` (e_l,
  Eq. 8), ``localization_max_m``, ``std_mean_m`` (mean of sqrt(std_x^2 + std_y^2), what the
  localizer believes), and ``following_mean_m`` (the mean |true - desired| the summary
  table reports once a configuration is reached) with ``following_max_m`` when known.
* ``/swarm/plan`` (``inchworm.Plan``), per ``PlanMessage``: ``config``, ``n_anchors``,
  ``steps`` (groups), ``moving`` (robots of the first group) and the ``anchors`` of the
  first step (ids).
* ``/swarm/event`` (``inchworm.RobotEvent``), per ``RobotEvent``: ``robot``, ``kind``
  (lost / rejoined), ``lost`` (1 lost, 0 rejoined, for plotting) and ``reason``.

Every message also carries ``step`` (the run's global step, 0 = initial localization).
``PlotDeriver`` holds the little state needed (trajectory, latest plan, estimate and truth
of the latest steps); not thread-safe.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from typing import Any

from runtime.foxglove_scene import moving_robots, trajectory_configurations
from runtime.messages import EstimateMessage, Message, PlanMessage, RobotEvent, TruthSetMessage

MESSAGE_ENCODING = "json"
SCHEMA_ENCODING = "jsonschema"
TOPIC_PREFIXES = ("/robot/", "/swarm/")
DERIVED_TYPES = (EstimateMessage, TruthSetMessage, PlanMessage, RobotEvent)
"""Message types whose validated contents ``PlotDeriver.derive`` needs."""


def _number(description: str, kind: str = "number") -> dict[str, Any]:
    return {"type": kind, "description": description}


def _schema(title: str, description: str, properties: dict[str, dict[str, Any]], optional: tuple[str, ...] = ()) -> dict[str, Any]:
    return {"$schema": "https://json-schema.org/draft/2020-12/schema", "title": title, "description": description,
            "type": "object", "properties": properties, "required": [k for k in properties if k not in optional],
            "additionalProperties": False}


_STEP = _number("global step of the run (0 = initial localization)", "integer")
SCHEMAS: dict[str, dict[str, Any]] = {
    "inchworm.RobotEstimate": _schema("inchworm.RobotEstimate", "one robot's fused estimate after a step (SI units)", {
        "step": _STEP, "robot": _number("robot id", "integer"),
        "x": _number("estimated x (m)"), "y": _number("estimated y (m)"), "heading": _number("estimated heading (rad)"),
        "std_x": _number("standard deviation of x (m)"), "std_y": _number("standard deviation of y (m)"),
        "std_heading": _number("standard deviation of the heading (rad)"),
        "anchor": _number("1 anchor (stood still this step), 0 moved, -1 unknown", "integer"),
    }),
    "inchworm.RobotTruth": _schema("inchworm.RobotTruth", "one robot's true pose after a step (simulation or motion capture)", {
        "step": _STEP, "robot": _number("robot id", "integer"),
        "x": _number("true x (m)"), "y": _number("true y (m)"), "heading": _number("true heading (rad)"),
    }),
    "inchworm.RobotError": _schema("inchworm.RobotError", "one robot's errors after a step", {
        "step": _STEP, "robot": _number("robot id", "integer"), "config": _number("configuration the step heads for (1-based, 0 unknown)", "integer"),
        "localization_m": _number("|true - estimated position| (m), the per-robot term of e_l (Eq. 8)"),
        "dx": _number("estimated - true x (m)"), "dy": _number("estimated - true y (m)"),
        "dheading": _number("estimated - true heading, wrapped to [-pi, pi) (rad)"),
        "following_m": _number("|true - desired position| of the configuration (m)"),
    }, optional=("following_m",)),
    "inchworm.SwarmError": _schema("inchworm.SwarmError", "the swarm's errors after a step", {
        "step": _STEP, "config": _number("configuration the step heads for (1-based, 0 unknown)", "integer"),
        "localization_mean_m": _number("e_l (Eq. 8): mean |true - estimated position| (m)"),
        "localization_max_m": _number("largest |true - estimated position| (m)"),
        "std_mean_m": _number("mean position standard deviation sqrt(std_x^2 + std_y^2) the localizer reports (m)"),
        "following_mean_m": _number("mean |true - desired position| (m)"),
        "following_max_m": _number("largest |true - desired position| (m)"),
    }, optional=("following_mean_m", "following_max_m")),
    "inchworm.Plan": _schema("inchworm.Plan", "the coordinator's plan towards a configuration", {
        "step": _STEP, "config": _number("desired configuration (1-based)", "integer"),
        "n_anchors": _number("anchors of the largest step", "integer"), "steps": _number("steps (groups) of the plan", "integer"),
        "moving": _number("robots moving in the first step", "integer"),
        "anchors": {"type": "array", "items": {"type": "integer"}, "description": "robots standing still in the first step"},
    }),
    "inchworm.RobotEvent": _schema("inchworm.RobotEvent", "a robot lost or rejoining the run", {
        "step": _STEP, "robot": _number("robot id", "integer"), "kind": {"type": "string", "enum": ["lost", "rejoined"]},
        "lost": _number("1 lost, 0 rejoined", "integer"), "reason": {"type": "string", "description": "why"},
    }),
}
SCHEMA_BYTES = {name: json.dumps(schema, separators=(",", ":")).encode() for name, schema in SCHEMAS.items()}


def is_plot_topic(topic: str) -> bool:
    return topic.startswith(TOPIC_PREFIXES)


def _dumps(obj: Mapping[str, Any]) -> bytes:
    """Compact JSON; non-finite numbers raise ``ValueError`` (JSON has none)."""
    return json.dumps(obj, separators=(",", ":"), allow_nan=False).encode()


def _wrap(angle: float) -> float:
    return (angle + math.pi) % (2 * math.pi) - math.pi


class PlotDeriver:
    """Raw messages -> ``(topic, schema name, JSON bytes)`` of the plottable channels (module docstring)."""

    def __init__(self, trajectory: Any = None) -> None:
        self.configurations = trajectory_configurations(trajectory)
        self.plan: PlanMessage | None = None
        self.estimates: dict[int, EstimateMessage] = {}  # step -> estimate, until its truth came
        self.truths: dict[int, TruthSetMessage] = {}  # step -> truth set, until its estimate came
        self.robots: tuple[int, ...] = ()  # the robots of the latest estimate (a plan lists only who moves)

    def derive(self, msg: Message) -> list[tuple[str, str, bytes]]:
        if isinstance(msg, EstimateMessage):
            out = self._estimate(msg)
            truth = self.truths.pop(msg.step, None)
            if truth is None:
                self._keep(self.estimates, msg.step, msg)
            else:
                out += self._errors(msg, truth)
            return out
        if isinstance(msg, TruthSetMessage):
            out = [(f"/robot/{int(r)}/truth", "inchworm.RobotTruth",
                    _dumps({"step": msg.step, "robot": int(r), "x": float(p[0]), "y": float(p[1]), "heading": float(p[2])}))
                   for r, p in zip(msg.ids, msg.poses)]
            estimate = self.estimates.pop(msg.step, None)
            if estimate is None:
                self._keep(self.truths, msg.step, msg)
            else:
                out += self._errors(estimate, msg)
            return out
        if isinstance(msg, PlanMessage):
            self.plan = msg
            robots = sorted({r for group in msg.groups for r in group} | set(self.robots))
            first = set(msg.groups[0]) if msg.groups else set()
            return [("/swarm/plan", "inchworm.Plan", _dumps({
                "step": msg.step, "config": msg.config, "n_anchors": msg.n_anchors, "steps": len(msg.groups),
                "moving": len(first), "anchors": [int(r) for r in robots if r not in first]}))]
        if isinstance(msg, RobotEvent):
            return [("/swarm/event", "inchworm.RobotEvent", _dumps({
                "step": msg.step, "robot": int(msg.robot), "kind": msg.kind, "lost": int(msg.kind == "lost"), "reason": msg.reason}))]
        return []

    @staticmethod
    def _keep(store: dict, step: int, msg: Message, depth: int = 4) -> None:
        store[step] = msg
        for old in sorted(store)[:-depth]:  # a step whose partner never comes is forgotten
            del store[old]

    def _estimate(self, msg: EstimateMessage) -> list[tuple[str, str, bytes]]:
        self.robots = msg.ids
        moving = moving_robots(self.plan, msg.step)
        out = []
        for robot, pose, cov in zip(msg.ids, msg.poses, msg.cov):
            anchor = -1 if moving is None else int(robot not in moving)
            out.append((f"/robot/{int(robot)}/estimate", "inchworm.RobotEstimate", _dumps({
                "step": msg.step, "robot": int(robot), "x": float(pose[0]), "y": float(pose[1]), "heading": float(pose[2]),
                "std_x": math.sqrt(max(cov[0][0], 0.0)), "std_y": math.sqrt(max(cov[1][1], 0.0)),
                "std_heading": math.sqrt(max(cov[2][2], 0.0)), "anchor": anchor})))
        return out

    def _config(self, step: int) -> int:
        """The configuration ``step`` heads for under the current plan (0 if the plan does not cover it)."""
        return self.plan.config if moving_robots(self.plan, step) is not None else 0

    def _errors(self, estimate: EstimateMessage, truth: TruthSetMessage) -> list[tuple[str, str, bytes]]:
        true = dict(zip(truth.ids, truth.poses))
        config = self._config(estimate.step)
        desired = self.configurations[config - 1] if self.configurations and 1 <= config <= len(self.configurations) else None
        out, loc, follow, std = [], [], [], []
        for robot, pose, cov in zip(estimate.ids, estimate.poses, estimate.cov):
            t = true.get(robot)
            if t is None:
                continue
            dx, dy = pose[0] - t[0], pose[1] - t[1]
            row = {"step": estimate.step, "robot": int(robot), "config": config, "localization_m": math.hypot(dx, dy),
                   "dx": dx, "dy": dy, "dheading": _wrap(pose[2] - t[2])}
            loc.append(row["localization_m"])
            std.append(math.sqrt(max(cov[0][0], 0.0) + max(cov[1][1], 0.0)))
            if desired is not None and robot in desired:
                row["following_m"] = math.hypot(t[0] - desired[robot][0], t[1] - desired[robot][1])
                follow.append(row["following_m"])
            out.append((f"/robot/{int(robot)}/error", "inchworm.RobotError", _dumps(row)))
        if loc:
            swarm = {"step": estimate.step, "config": config, "localization_mean_m": sum(loc) / len(loc),
                     "localization_max_m": max(loc), "std_mean_m": sum(std) / len(std)}
            if follow:
                swarm["following_mean_m"], swarm["following_max_m"] = sum(follow) / len(follow), max(follow)
            out.append(("/swarm/error", "inchworm.SwarmError", _dumps(swarm)))
        return out
