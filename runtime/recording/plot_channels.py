"""Plottable JSON channels of a run, derived from the raw msgpack messages (docs/recording.md).

Foxglove (Plot, Raw Message, State Transitions panels) and PlotJuggler read MCAP channels
whose message encoding is ``json`` and whose schema is a ``jsonschema``; Foxglove cannot decode
our msgpack, and PlotJuggler names a msgpack array's entries by position, not robot id. The recorder
(``runtime.recording.mcap_log``) writes these channels next to the raw ones, each message right after the
raw one it comes from, with its ``stamp_ns`` as publish time. Every field is a flat number (or, for plans and events, a short string or id list),
so a plot path is simply ``/robot/3/estimate.x``. Units SI: m, rad.

Topics and schemas (``SCHEMAS``):

* ``/robot/<id>/estimate`` (``inchworm.RobotEstimate``), per ``EstimateMessage``: the fused
  estimate ``x``, ``y``, ``heading`` and its standard deviations ``std_x``, ``std_y``,
  ``std_heading`` (square roots of the covariance diagonal), ``anchor`` (1 if the robot
  stood still in this step under the current plan, 0 if it moved, -1 unknown), ``config``
  (the configuration the step heads for, 0 unknown). When the truth of the step is known
  (``TruthSetMessage``: simulated runs, motion capture) also the true pose ``true_x``,
  ``true_y``, ``true_heading``, ``localization_m`` = |true - estimated position| (the
  per-robot term of e_l, Eq. 8), ``dx``, ``dy``, ``dheading`` (estimate - truth, heading
  wrapped to [-pi, pi)) and, with the desired configuration known (``PlanMessage`` +
  trajectory metadata), ``following_m`` = |true - desired position|. Everything about one
  robot at one step is one message: each derived message costs an MCAP record while
  recording. The coordinator publishes a step's truth before its estimate; a truth that
  comes after its estimate makes the estimate's messages be written again with it.
* ``/swarm/error`` (``inchworm.SwarmError``), per step with estimate and truth: ``localization_mean_m`` (e_l,
  Eq. 8), ``localization_max_m``, ``std_mean_m`` (mean of sqrt(std_x^2 + std_y^2), what the
  localizer believes), and ``following_mean_m`` (the mean |true - desired| the summary
  table reports once a configuration is reached) with ``following_max_m`` when known.
* ``/swarm/plan`` (``inchworm.Plan``), per ``PlanMessage``: ``config``, ``n_anchors``,
  ``steps`` (groups), ``moving`` (robots of the first group) and the ``anchors`` of the
  first step (ids).
* ``/swarm/event`` (``inchworm.RobotEvent``), per ``RobotEvent``: ``robot``, ``kind``
  (lost / rejoined), ``lost`` (1 lost, 0 rejoined, for plotting) and ``reason``.

Every message also carries ``step`` (the run's global step, 0 = initial localization).
Per-robot messages are written as JSON text from templates with 9 significant digits (no
dicts, no ``json.dumps``): the recorder derives n of them per step (``swarm bench record``).
``PlotDeriver`` holds the little state needed (trajectory, latest plan, estimate and truth
of the latest steps); not thread-safe.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from typing import Any, TypeVar

from runtime.recording.foxglove_scene import moving_robots, trajectory_configurations
from runtime.wire.messages import EstimateMessage, Message, PlanMessage, RobotEvent, TruthSetMessage

M = TypeVar("M", bound=Message)
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


_TRUTH_FIELDS = ("true_x", "true_y", "true_heading", "localization_m", "dx", "dy", "dheading", "following_m")
_STEP = _number("global step of the run (0 = initial localization)", "integer")
SCHEMAS: dict[str, dict[str, Any]] = {
    "inchworm.RobotEstimate": _schema("inchworm.RobotEstimate",
                                      "one robot after a step: estimate, uncertainty, and truth and errors when known (SI units)", {
        "step": _STEP, "robot": _number("robot id", "integer"),
        "config": _number("configuration the step heads for (1-based, 0 unknown)", "integer"),
        "x": _number("estimated x (m)"), "y": _number("estimated y (m)"), "heading": _number("estimated heading (rad)"),
        "std_x": _number("standard deviation of x (m)"), "std_y": _number("standard deviation of y (m)"),
        "std_heading": _number("standard deviation of the heading (rad)"),
        "anchor": _number("1 anchor (stood still this step), 0 moved, -1 unknown", "integer"),
        "true_x": _number("true x (m)"), "true_y": _number("true y (m)"), "true_heading": _number("true heading (rad)"),
        "localization_m": _number("|true - estimated position| (m), the per-robot term of e_l (Eq. 8)"),
        "dx": _number("estimated - true x (m)"), "dy": _number("estimated - true y (m)"),
        "dheading": _number("estimated - true heading, wrapped to [-pi, pi) (rad)"),
        "following_m": _number("|true - desired position| of the configuration (m)"),
    }, optional=_TRUTH_FIELDS),
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


# Per-robot messages as %-templates: 9 significant digits (nanometres at metres), about 5x cheaper than
# repr() per number; the recorder writes n of them per step.
_ESTIMATE = ('{"step":%d,"robot":%d,"config":%d,"x":%.9g,"y":%.9g,"heading":%.9g,"std_x":%.9g,"std_y":%.9g,'
             '"std_heading":%.9g,"anchor":%d')
_TRUTH = ',"true_x":%.9g,"true_y":%.9g,"true_heading":%.9g,"localization_m":%.9g,"dx":%.9g,"dy":%.9g,"dheading":%.9g'
_FOLLOWING = ',"following_m":%.9g'


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
            self.robots = msg.ids
            truth = self.truths.pop(msg.step, None)
            if truth is None:  # its truth may still come (or never: hardware)
                self._keep(self.estimates, msg.step, msg)
            return self._robots(msg, truth)
        if isinstance(msg, TruthSetMessage):
            estimate = self.estimates.pop(msg.step, None)
            if estimate is None:
                self._keep(self.truths, msg.step, msg)
                return []
            return self._robots(estimate, msg)
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
    def _keep(store: dict[int, M], step: int, msg: M, depth: int = 4) -> None:
        store[step] = msg
        for old in sorted(store)[:-depth]:  # a step whose partner never comes is forgotten
            del store[old]

    def _config(self, step: int) -> int:
        """The configuration ``step`` heads for under the current plan (0 if the plan does not cover it)."""
        return self.plan.config if self.plan is not None and moving_robots(self.plan, step) is not None else 0

    def _robots(self, estimate: EstimateMessage, truth: TruthSetMessage | None) -> list[tuple[str, str, bytes]]:
        """One ``/robot/<id>/estimate`` message per robot (with truth and errors when ``truth`` is given),
        then ``/swarm/error`` when there is a truth."""
        step, config = int(estimate.step), self._config(estimate.step)
        moving = moving_robots(self.plan, estimate.step)
        true = dict(zip(truth.ids, truth.poses, strict=True)) if truth is not None else {}
        desired = self.configurations[config - 1] if self.configurations and 1 <= config <= len(self.configurations) else None
        out, loc, follow, std = [], [], [], []
        for robot, pose, cov in zip(estimate.ids, estimate.poses, estimate.cov, strict=True):
            anchor = -1 if moving is None else int(robot not in moving)
            values: tuple[float, ...] = (pose[0], pose[1], pose[2], math.sqrt(max(cov[0][0], 0.0)), math.sqrt(max(cov[1][1], 0.0)),
                      math.sqrt(max(cov[2][2], 0.0)))
            text = _ESTIMATE % (step, robot, config, *values, anchor)
            t = true.get(robot)
            if t is not None:
                dx, dy = pose[0] - t[0], pose[1] - t[1]
                loc.append(math.hypot(dx, dy))
                std.append(math.hypot(values[3], values[4]))
                values += (t[0], t[1], t[2], loc[-1], dx, dy, _wrap(pose[2] - t[2]))
                text += _TRUTH % values[6:]
                if desired is not None and robot in desired:
                    follow.append(math.hypot(t[0] - desired[robot][0], t[1] - desired[robot][1]))
                    values += (follow[-1],)
                    text += _FOLLOWING % follow[-1]
            if not math.isfinite(math.fsum(values)):  # JSON has no NaN or infinity
                raise ValueError(f"non-finite value in the estimate of robot {robot} at step {step}")
            out.append((f"/robot/{int(robot)}/estimate", "inchworm.RobotEstimate", (text + "}").encode()))
        if loc:
            swarm = {"step": step, "config": config, "localization_mean_m": sum(loc) / len(loc),
                     "localization_max_m": max(loc), "std_mean_m": sum(std) / len(std)}
            if follow:
                swarm["following_mean_m"], swarm["following_max_m"] = sum(follow) / len(follow), max(follow)
            out.append(("/swarm/error", "inchworm.SwarmError", _dumps(swarm)))
        return out
