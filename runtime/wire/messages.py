"""Messages between the swarm processes: typed, versioned, msgpack-encoded (contract: docs/protocol.md).

Every message is a frozen dataclass with a ``TYPE`` name, a major ``VERSION`` and the
header ``run``, ``step`` (global step counter), ``stamp_ns`` (wall-clock publish time,
ns), then its own fields in SI units. On the wire it is a msgpack map
``{"type": TYPE, "v": VERSION, <field>: <value>, ...}`` with arrays as plain lists.

Each field's ``Wire`` spec (kind, shape, unit, limits) is the one source of truth: it
validates construction and decoding and generates ``json_schema``. Building a message
with bad values raises ``MessageError`` at the producer; ``decode`` raises nothing but
``MessageError`` for any input, and ``decode_or_drop`` turns that into a counted,
logged drop so a bad message never kills a process.
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import logging
import math
import re
import sys
import threading
import time
from collections.abc import Callable, Collection, Iterable, Iterator
from dataclasses import Field, dataclass, field, fields
from typing import Any, ClassVar, TypeVar, cast, overload

import msgpack
import numpy as np

from runtime.errors import SwarmInputError
from runtime.models.state import Observations, SwarmEstimate
from runtime.wire.keys import (
    COORD_LEAVES,
    MAX_ROBOT_ID,
    ROBOT_LEAVES,
    RUN_PATTERN,
    KeyspaceError,
    contact_key,
    coord_key,
    estop_ack_key,
    estop_key,
    link_stats_key,
    parse_key,
    physics_key,
    robot_key,
    truth_key,
    truths_key,
)

MAX_INT = MAX_ROBOT_ID  # every integer field, robot ids included, is in [0, 2^63 - 1]
MAX_ITEMS = 100_000  # longest list of any field (robots, observations, groups)
MAX_TEXT = 2_000  # longest string field (characters)
SMALL_BYTES = 64 * 2**10  # commands, requests, answers, stops: a few hundred bytes in practice
LIST_BYTES = 2**20  # messages with one list per robot seen or planned (observations, plans, link replies and stats)
SWARM_BYTES = 4 * 2**20  # messages with a row per robot of the swarm (estimates, truth sets): ~110 B a robot
MAX_MESSAGE_BYTES = SWARM_BYTES  # the largest message of any type; Zenoh drops larger ones (transport.MAX_WIRE_BYTES)
ANGLE_SLACK = 1e-9  # rad tolerated beyond [-pi, pi] for bearings
STATES = ("accepted", "done", "refused")
LINK_REQUESTS = ("command", "observe", "estop", "reset")
LINK_REPLIES = ("accepted", "done", "refused", "observation", "estopped", "reset", "lost")
REASONS = (
    "undecodable",
    "not-a-map",
    "unknown-type",
    "unexpected-type",
    "version",
    "missing-field",
    "wrong-type",
    "non-finite",
    "out-of-range",
    "size",
    "invalid",
    "unknown-id",
    "wrong-key",
    "foreign",
)

_log = logging.getLogger(__name__)


class MessageError(SwarmInputError):
    """A message that cannot be built or decoded; the text names the field and what is wrong.

    ``where`` is the field (``"ObservationReport.ranges[3]"``) or ``"message"``/``"key"``;
    ``reason`` is one of ``REASONS`` (for drop counters); after ``decode``, ``header``
    holds the header fields that could be read (type, run, step, robot), so an agent
    can refuse a command it cannot decode (``refusal_status``).
    """

    def __init__(self, where: str, problem: str, reason: str) -> None:
        super().__init__(f"{where}: {problem}")
        self.where = where
        self.reason = reason
        self.header: dict[str, Any] = {}


@dataclass(frozen=True)
class Wire:
    """How one field travels: element ``kind``, list ``shape``, ``unit``, limits and meaning.

    ``kind`` is ``"int"`` (integer in [0, 2^63 - 1]), ``"id"`` (a robot id, same range),
    ``"float"`` (finite; ints accepted) or ``"str"``. ``shape`` has one entry per list
    level: an int is a fixed length, a letter a length shared by every field of the
    message using that letter, None any length (up to ``MAX_ITEMS``). An ``optional`` field
    was added after its type's first version: a message without it decodes to the default.
    """

    kind: str
    doc: str
    unit: str = ""
    shape: tuple[int | str | None, ...] = ()
    minimum: float | None = None
    maximum: float | None = None
    slack: float = 0.0
    choices: tuple[str, ...] = ()
    pattern: str | None = None
    max_length: int = MAX_TEXT
    optional: bool = False


def _wire(kind: str, doc: str, default: Any = dataclasses.MISSING, **spec: Any) -> Any:
    if default is not dataclasses.MISSING:
        return field(default=default, metadata={"wire": Wire(kind, doc, optional=True, **spec)})
    return field(metadata={"wire": Wire(kind, doc, **spec)})


def _show(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def _scalar(x: Any, wire: Wire, path: str) -> Any:
    if wire.kind == "str":
        if not isinstance(x, str):
            raise MessageError(path, f"{_show(x)} is a {type(x).__name__}, expected a string", "wrong-type")
        if len(x) > wire.max_length:
            raise MessageError(path, f"{len(x)} characters, at most {wire.max_length} allowed", "size")
        if wire.choices and x not in wire.choices:
            raise MessageError(path, f"{_show(x)} is not one of {', '.join(wire.choices)}", "out-of-range")
        if wire.pattern and not _compiled(wire.pattern).fullmatch(x):
            raise MessageError(path, f"{_show(x)} does not match {wire.pattern}", "out-of-range")
        return str(x)
    expected = "a number" if wire.kind == "float" else "an integer"
    numeric = (int, float, np.integer, np.floating) if wire.kind == "float" else (int, np.integer)
    if isinstance(x, (bool, np.bool_)) or not isinstance(x, numeric):
        raise MessageError(path, f"{_show(x)} is a {type(x).__name__}, expected {expected}", "wrong-type")
    if wire.kind != "float":
        if not 0 <= x <= MAX_INT:
            raise MessageError(path, f"{_show(x)} is outside [0, 2^63 - 1]", "out-of-range")
        return int(x)
    try:
        v = float(x)
    except OverflowError:
        raise MessageError(path, f"{_show(x)} is too large for a float", "out-of-range") from None
    if not math.isfinite(v):
        raise MessageError(path, f"{v!r} is not finite", "non-finite")
    lo = -math.inf if wire.minimum is None else wire.minimum - wire.slack
    hi = math.inf if wire.maximum is None else wire.maximum + wire.slack
    if not lo <= v <= hi:
        problem = "is negative" if wire.minimum == 0 and wire.maximum is None else f"is outside [{lo:.10g}, {hi:.10g}]"
        raise MessageError(path, f"{v!r} {problem}", "out-of-range")
    return v


def _plain_leaves(values: list[Any] | tuple[Any, ...], wire: Wire) -> tuple[Any, ...] | None:
    """``values`` as a tuple if all are plain valid floats (or ints), the common case; else None."""
    if wire.kind == "float":
        if not set(map(type, values)) <= {float}:
            return None
        lo = -math.inf if wire.minimum is None else wire.minimum - wire.slack
        hi = math.inf if wire.maximum is None else wire.maximum + wire.slack
        ok = not values or (math.isfinite(sum(values)) and lo <= min(values) and max(values) <= hi)
    else:
        plain = wire.kind != "str" and set(map(type, values)) <= {int}
        ok = plain and (not values or 0 <= min(values) and max(values) <= MAX_INT)
    return tuple(values) if ok else None


_compiled: Callable[[str], re.Pattern[str]] = functools.cache(re.compile)


def _fast_scalar(wire: Wire) -> Callable[[Any], bool]:
    """A predicate true for the values ``_scalar`` returns unchanged: an exact int, float or str passing every
    check of ``wire`` (the common case, a few comparisons); anything else takes ``_convert``'s path."""
    if wire.kind in ("int", "id"):
        return lambda x: type(x) is int and 0 <= x <= MAX_INT
    if wire.kind == "float":  # finite bounds: NaN fails every comparison and infinity the bounds
        lo = -sys.float_info.max if wire.minimum is None else wire.minimum - wire.slack
        hi = sys.float_info.max if wire.maximum is None else wire.maximum + wire.slack
        return lambda x: type(x) is float and lo <= x <= hi
    match = _compiled(wire.pattern).fullmatch if wire.pattern else None
    choices, longest = frozenset(wire.choices), wire.max_length
    return lambda x: (type(x) is str and len(x) <= longest and (not choices or x in choices)
                      and (match is None or match(x) is not None))


def _plain_nested(value: Any, wire: Wire, dims: dict[str, tuple[int, str]], path: Callable[[], str]) -> tuple[Any, ...] | None:
    """``value`` (a list field) as nested tuples if it is well formed with plain valid leaves, the common case,
    checked level by level in C (``map``, ``set``, ``itertools.chain``); else None (``_convert`` then names the
    problem). Records the length of a lettered first dimension in ``dims`` (at ``path()``) as ``_convert`` does."""
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if type(value) is not list and type(value) is not tuple:
        return None
    n, first = len(value), wire.shape[0]
    if n > MAX_ITEMS or (isinstance(first, int) and n != first):
        return None
    seen = dims.get(first) if isinstance(first, str) else None
    if seen is not None and seen[0] != n:
        return None
    if len(wire.shape) == 1:
        plain = _plain_leaves(value, wire)
    else:
        level = value
        for dim in wire.shape[1:]:
            lengths = set(map(len, level)) if set(map(type, level)) <= {list, tuple} else {-1}
            if isinstance(dim, str) or -1 in lengths or (isinstance(dim, int) and not lengths <= {dim}) or max(lengths, default=0) > MAX_ITEMS:
                return None
            level = list(itertools.chain.from_iterable(level))
        if _plain_leaves(level, wire) is None:
            return None
        plain = _nested_tuples(value, len(wire.shape))
    if plain is not None and isinstance(first, str) and seen is None:
        dims[first] = (n, path())
    return plain


def _nested_tuples(value: Any, depth: int) -> tuple[Any, ...]:
    """A list nested ``depth`` levels as nested tuples (two levels in C: the common case of a row per robot)."""
    if depth <= 2:
        return tuple(value) if depth == 1 else tuple(map(tuple, value))
    return tuple(_nested_tuples(v, depth - 1) for v in value)


def _field_plan(cls: type) -> tuple[tuple[str, Wire, Callable[[Any], bool] | None], ...]:
    """Per field of message type ``cls``: its name, wire spec and fast scalar check (None for lists)."""
    return tuple((f.name, f.metadata["wire"], None if f.metadata["wire"].shape else _fast_scalar(f.metadata["wire"]))
                 for f in _fields(cls))


_plan: Callable[[type], tuple[tuple[str, Wire, Callable[[Any], bool] | None], ...]] = functools.cache(_field_plan)  # once per type


def _convert(value: Any, wire: Wire, path: str, dims: dict[str, tuple[int, str]], depth: int = 0) -> Any:
    """``value`` validated and normalised to Python scalars and nested tuples."""
    if depth == len(wire.shape):
        return _scalar(value, wire, path)
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if not isinstance(value, (list, tuple)):
        raise MessageError(path, f"{_show(value)} is a {type(value).__name__}, expected a list", "wrong-type")
    n, dim = len(value), wire.shape[depth]
    if n > MAX_ITEMS:
        raise MessageError(path, f"{n} items, at most {MAX_ITEMS} allowed", "size")
    if isinstance(dim, int) and n != dim:
        raise MessageError(path, f"{n} items, expected {dim}", "size")
    if isinstance(dim, str):
        first, where = dims.setdefault(dim, (n, path))
        if n != first:
            raise MessageError(path, f"{n} items, but {where} has {first}", "size")
    if depth == len(wire.shape) - 1:
        plain = _plain_leaves(value, wire)
        if plain is not None:
            return plain
    return tuple(_convert(v, wire, f"{path}[{i}]", dims, depth + 1) for i, v in enumerate(value))


# ``dataclasses.fields(cls)``, computed once per message type (it is on every hot path). Typed as a plain
# callable: mypy does not see a dataclass type as hashable, which the cache requires.
_fields: Callable[[type], tuple[Field[Any], ...]] = functools.cache(fields)


def _leaves(value: Any, path: str, depth: int) -> Iterator[tuple[str, Any]]:
    if depth == 0:
        yield path, value
    else:
        for i, v in enumerate(value):
            yield from _leaves(v, f"{path}[{i}]", depth - 1)


@dataclass(frozen=True, kw_only=True)
class Message:
    """Header of every message; ``stamp_ns`` defaults to the construction time."""

    TYPE: ClassVar[str] = ""
    VERSION: ClassVar[int] = 1
    LEAF: ClassVar[str] = ""  # last key chunk this type travels on (runtime.wire.keys)
    MAX_BYTES: ClassVar[int] = SMALL_BYTES  # a larger payload on this type's keys is dropped before it is parsed

    run: str = _wire("str", "run id", pattern=RUN_PATTERN, max_length=64)
    step: int = _wire("int", "global step counter of the run: 0 = initial localization, motion steps from 1")
    stamp_ns: int = field(
        default_factory=time.time_ns, metadata={"wire": Wire("int", "wall-clock publish time since the Unix epoch", unit="ns")}
    )

    def __post_init__(self) -> None:
        dims: dict[str, tuple[int, str]] = {}
        for name, wire, fast in _plan(type(self)):
            value = getattr(self, name)
            if fast is not None:
                if fast(value):
                    continue  # already the plain valid scalar ``_convert`` would return
            elif (plain := _plain_nested(value, wire, dims, lambda: f"{self.TYPE}.{name}")) is not None:  # noqa: B023 - called at once
                object.__setattr__(self, name, plain)
                continue
            object.__setattr__(self, name, _convert(value, wire, f"{self.TYPE}.{name}", dims))
        self._check()

    def _check(self) -> None:
        """Rules across fields (overridden where a type has some)."""


@dataclass(frozen=True, kw_only=True)
class MotionCommand(Message):
    """Coordinator -> agent: in the body frame, turn by ``turn_rad``, then drive ``drive_m`` straight."""

    TYPE: ClassVar[str] = "MotionCommand"
    LEAF: ClassVar[str] = "cmd"

    robot: int = _wire("id", "the robot that moves")
    config: int = _wire("int", "desired configuration the step heads for: k for C_dk (1-based, as in the paper)")
    turn_rad: float = _wire("float", "turn before driving, counter-clockwise positive; agents refuse abs(turn) > their limit", unit="rad")
    drive_m: float = _wire("float", "straight distance after the turn; agents refuse < 0 or > their limit", unit="m")
    start_pose: tuple[float, ...] = _wire(
        "float", "optional: the coordinator's estimate [x, y, heading] of the robot before the move, "
                 "for the agent's workspace check; [] if unknown", default=(), unit="m, m, rad", shape=(None,))
    cmd_id: int = _wire("int", "optional: the coordinator's id of this command (random, never 0), echoed in every "
                               "Status answering it; 0 = none", default=0)
    epoch: int = _wire("int", "optional: the epoch of the coordinator that sent it (random, never 0; its liveliness token "
                              "names it); agents obey one epoch at a time and refuse 0 (docs/protocol.md, Coordinator epochs)",
                       default=0)

    def _check(self) -> None:
        if len(self.start_pose) not in (0, 3):
            raise MessageError("MotionCommand.start_pose", f"{len(self.start_pose)} values, expected 3 or none", "size")


@dataclass(frozen=True, kw_only=True)
class ObserveRequest(Message):
    """Coordinator -> agent: publish your neighbour observations for ``step``."""

    TYPE: ClassVar[str] = "ObserveRequest"
    LEAF: ClassVar[str] = "observe"

    robot: int = _wire("id", "the robot asked")
    epoch: int = _wire("int", "optional: the epoch of the coordinator that sent it (random, never 0; its liveliness token "
                              "names it); agents obey one epoch at a time and refuse 0 (docs/protocol.md, Coordinator epochs)",
                       default=0)


@dataclass(frozen=True, kw_only=True)
class Status(Message):
    """Agent -> coordinator: the state of the robot's command for ``step``."""

    TYPE: ClassVar[str] = "Status"
    LEAF: ClassVar[str] = "status"

    robot: int = _wire("id", "the robot reporting")
    state: str = _wire("str", "accepted (executing), done (executed) or refused (not executed)", choices=STATES)
    reason: str = _wire("str", "why the command was refused; empty unless refused")
    cmd_id: int = _wire("int", "optional: the cmd_id of the MotionCommand answered (0 if it could not be read); "
                               "a coordinator counts only answers carrying the id it sent", default=0)

    def _check(self) -> None:
        if (self.state == "refused") != bool(self.reason):
            problem = "is empty for a refusal" if self.reason == "" else f"{_show(self.reason)} given with state {self.state!r}"
            raise MessageError("Status.reason", f"{problem} (a reason is required iff state is 'refused')", "invalid")


RUN_STOPPED_REFUSAL = "the run was emergency-stopped"
"""How a refusal's reason begins when the robot refused because its whole run was e-stopped (not a fault of the
robot): ``"the run was emergency-stopped by <source> (<reason>)"``; a coordinator reads it as the run's stop."""


@dataclass(frozen=True, kw_only=True)
class ObservationReport(Message):
    """Agent -> coordinator: what ``robot`` observed after ``step`` (Eq. 20, its body frame)."""

    TYPE: ClassVar[str] = "ObservationReport"
    LEAF: ClassVar[str] = "obs"
    MAX_BYTES: ClassVar[int] = LIST_BYTES

    robot: int = _wire("id", "the observer")
    observed: tuple[int, ...] = _wire("id", "robots observed", shape=("n",))
    ranges: tuple[float, ...] = _wire("float", "distance to each observed robot", unit="m", shape=("n",), minimum=0.0)
    bearings: tuple[float, ...] = _wire(
        "float",
        "bearing of each observed robot in the observer's body frame",
        unit="rad",
        shape=("n",),
        minimum=-math.pi,
        maximum=math.pi,
        slack=ANGLE_SLACK,
    )

    def _check(self) -> None:
        if self.robot in self.observed:
            i = self.observed.index(self.robot)
            raise MessageError(f"ObservationReport.observed[{i}]", f"robot {self.robot} observes itself", "invalid")


@dataclass(frozen=True, kw_only=True)
class PlanMessage(Message):
    """Coordinator -> all: the plan of a configuration (``leg`` 0) or of one of its approach legs; ``groups[k]`` moves
    at step ``step + k``."""

    TYPE: ClassVar[str] = "PlanMessage"
    LEAF: ClassVar[str] = "plan"
    MAX_BYTES: ClassVar[int] = LIST_BYTES

    config: int = _wire("int", "desired configuration planned for: k for C_dk (1-based)")
    n_anchors: int = _wire("int", "anchors of the largest step (robots minus the smallest group)")
    groups: tuple[tuple[int, ...], ...] = _wire(
        "id", "ordered mobile groups, at least one, each non-empty, no robot twice", shape=(None, None)
    )
    leg: int = _wire("int", "optional: 0 = the configuration's plan; k >= 1 = its k-th approach leg, whose groups move only "
                     "the robots that go on from leg k - 1 (stopped at a staging point, waited, or in a group a cut leg left "
                     "unrun) or drive a correction (docs/bodies.md)", default=0)

    def _check(self) -> None:
        seen: set[int] = set()
        if not self.groups:
            raise MessageError("PlanMessage.groups", "a plan needs at least one group", "invalid")
        for g, group in enumerate(self.groups):
            if not group:
                raise MessageError(f"PlanMessage.groups[{g}]", "empty group", "invalid")
            for i, robot in enumerate(group):
                if robot in seen:
                    raise MessageError(f"PlanMessage.groups[{g}][{i}]", f"robot {robot} is in two groups", "invalid")
                seen.add(robot)


@dataclass(frozen=True, kw_only=True)
class EstimateMessage(Message):
    """Coordinator -> all: the fused estimate after ``step`` (runtime.models.state.SwarmEstimate)."""

    TYPE: ClassVar[str] = "EstimateMessage"
    LEAF: ClassVar[str] = "estimate"
    MAX_BYTES: ClassVar[int] = SWARM_BYTES

    ids: tuple[int, ...] = _wire("id", "robots, at least one, no duplicates; the rows below follow this order", shape=("n",))
    poses: tuple[tuple[float, ...], ...] = _wire("float", "[x, y, heading] per robot", unit="m, m, rad", shape=("n", 3))
    cov: tuple[tuple[tuple[float, ...], ...], ...] = _wire(
        "float", "3x3 covariance of (x, y, heading) per robot", unit="m^2, m*rad, rad^2", shape=("n", 3, 3)
    )

    def _check(self) -> None:
        if not self.ids:
            raise MessageError("EstimateMessage.ids", "an estimate needs at least one robot", "invalid")
        seen: set[int] = set()
        for i, robot in enumerate(self.ids):
            if robot in seen:
                raise MessageError(f"EstimateMessage.ids[{i}]", f"robot {robot} appears twice", "invalid")
            seen.add(robot)

    @classmethod
    def from_estimate(cls, estimate: SwarmEstimate, *, run: str, step: int, stamp_ns: int | None = None) -> EstimateMessage:
        """The message of ``estimate`` (stamped now unless ``stamp_ns`` is given)."""
        stamp = time.time_ns() if stamp_ns is None else stamp_ns
        return cls(run=run, step=step, stamp_ns=stamp, ids=estimate.ids, poses=estimate.poses, cov=estimate.cov)  # type: ignore[arg-type]  # arrays: converted by __post_init__

    def to_estimate(self) -> SwarmEstimate:
        """The ``SwarmEstimate`` this message carries."""
        return SwarmEstimate(np.array(self.ids, dtype=np.int64), np.array(self.poses, float), np.array(self.cov, float))


@dataclass(frozen=True, kw_only=True)
class TruthMessage(Message):
    """Simulated agent -> recorder (simulation only): the robot's true pose after ``step``."""

    TYPE: ClassVar[str] = "TruthMessage"
    LEAF: ClassVar[str] = "truth"

    robot: int = _wire("id", "the simulated robot")
    pose: tuple[float, ...] = _wire("float", "true [x, y, heading]", unit="m, m, rad", shape=(3,))


@dataclass(frozen=True, kw_only=True)
class TruthSetMessage(Message):
    """Coordinator -> simulated agents (simulation only): every robot's true pose after ``step``.

    The coordinator collects the agents' ``TruthMessage``s of a step and republishes them
    as one message, so each simulated agent receives one message per step instead of n.
    """

    TYPE: ClassVar[str] = "TruthSetMessage"
    LEAF: ClassVar[str] = "truths"
    MAX_BYTES: ClassVar[int] = SWARM_BYTES

    ids: tuple[int, ...] = _wire("id", "robots, at least one, no duplicates; the rows below follow this order", shape=("n",))
    poses: tuple[tuple[float, ...], ...] = _wire("float", "true [x, y, heading] per robot", unit="m, m, rad", shape=("n", 3))
    epoch: int = _wire("int", "optional: the epoch of the coordinator that sent it (random, never 0; its liveliness token "
                              "names it); agents obey one epoch at a time and refuse 0 (docs/protocol.md, Coordinator epochs)",
                       default=0)

    def _check(self) -> None:
        if not self.ids:
            raise MessageError("TruthSetMessage.ids", "a truth set needs at least one robot", "invalid")
        if len(set(self.ids)) != len(self.ids):
            raise MessageError("TruthSetMessage.ids", "a robot appears twice", "invalid")


@dataclass(frozen=True, kw_only=True)
class LinkRequest(Message):
    """Gateway agent -> link process: send this request to robot ``robot`` over its port (docs/gateway-protocol.md).

    ``command``: turn ``turn_rad`` then drive ``drive_m`` (already calibrated); ``observe``:
    report the observations of ``step``; ``estop`` / ``reset``: emergency stop / clear it.
    """

    TYPE: ClassVar[str] = "LinkRequest"
    LEAF: ClassVar[str] = "linkreq"

    robot: int = _wire("id", "the robot behind the link")
    kind: str = _wire("str", "command, observe, estop or reset", choices=LINK_REQUESTS)
    turn_rad: float = _wire("float", "command only (else 0): turn before driving, counter-clockwise positive", unit="rad")
    drive_m: float = _wire("float", "command only (else 0): straight distance after the turn", unit="m", minimum=0.0)
    start_pose: tuple[float, ...] = _wire(
        "float", "optional, command only: the MotionCommand's start pose, for the record; the link checks the workspace "
                 "from the coordinator's own command and its reckoning, never from this; [] if unknown",
        default=(), unit="m, m, rad", shape=(None,))
    epoch: int = _wire("int", "command only: the epoch of the coordinator whose MotionCommand this is (the link forwards a "
                              "motion only of the live coordinator's run and only as that coordinator commanded it); 0 = none",
                       default=0)

    def _check(self) -> None:
        if len(self.start_pose) not in (0, 3):
            raise MessageError("LinkRequest.start_pose", f"{len(self.start_pose)} values, expected 3 or none", "size")


@dataclass(frozen=True, kw_only=True)
class LinkReply(Message):
    """Link process -> gateway agent: what robot ``robot`` answered to the request of ``step``, or that it is lost.

    ``observation`` carries the raw (uncalibrated) measurements; ``refused`` and ``lost``
    carry a ``reason``.
    """

    TYPE: ClassVar[str] = "LinkReply"
    LEAF: ClassVar[str] = "linkrep"
    MAX_BYTES: ClassVar[int] = LIST_BYTES

    robot: int = _wire("id", "the robot behind the link")
    kind: str = _wire("str", "accepted, done, refused, observation, estopped, reset or lost", choices=LINK_REPLIES)
    reason: str = _wire("str", "why (refused, lost); else empty")
    observed: tuple[int, ...] = _wire("id", "observation only: robots observed", shape=("n",))
    ranges: tuple[float, ...] = _wire("float", "observation only: distance to each, as measured", unit="m", shape=("n",), minimum=0.0)
    bearings: tuple[float, ...] = _wire("float", "observation only: bearing of each in the body frame, as measured", unit="rad", shape=("n",))


@dataclass(frozen=True, kw_only=True)
class LinkStats(Message):
    """Link process -> recorder, tools: counters of one serial/radio port since the link started (``step`` 0).

    Published every ``stats_period_s`` of the gateway config and when the link stops.
    Round-trip times are request sent -> first answer received, over the last 1000 answers.
    """

    TYPE: ClassVar[str] = "LinkStats"
    LEAF: ClassVar[str] = "stats"
    MAX_BYTES: ClassVar[int] = LIST_BYTES

    port: str = _wire("str", "port name from the gateway config", pattern=RUN_PATTERN, max_length=64)
    robots: tuple[int, ...] = _wire("id", "robots behind the port", shape=(None,))
    frames_sent: int = _wire("int", "frames written to the port, retransmissions included")
    frames_received: int = _wire("int", "valid frames read from the port")
    retransmissions: int = _wire("int", "requests sent again for want of an answer")
    crc_errors: int = _wire("int", "frames rejected for their CRC")
    length_errors: int = _wire("int", "false starts rejected for their length or given up on a quiet line")
    skipped_bytes: int = _wire("int", "bytes skipped while resynchronising")
    timeouts: int = _wire("int", "requests that exhausted their retries")
    rtt_ms_median: float = _wire("float", "median round trip (0 before the first answer)", unit="ms", minimum=0.0)
    rtt_ms_p90: float = _wire("float", "90th percentile round trip", unit="ms", minimum=0.0)
    rtt_ms_max: float = _wire("float", "longest round trip", unit="ms", minimum=0.0)
    lost: tuple[int, ...] = _wire("id", "robots that stopped answering", shape=(None,))
    rejected: int = _wire("int", "requests dropped unsent: undecodable, foreign, not representable on the wire, "
                                 "beyond the gateway config's limits, or unauthorised", default=0)
    unauthorised: int = _wire("int", "of rejected: requests no live coordinator commanded (forged, stale, future, another "
                                     "epoch's, or while no coordinator is alive)", default=0)


@dataclass(frozen=True, kw_only=True)
class EmergencyStop(Message):
    """Operator or launcher -> every agent and link of the run: stop every robot now (latched on the robots)."""

    TYPE: ClassVar[str] = "EmergencyStop"
    LEAF: ClassVar[str] = "estop"

    source: str = _wire("str", "who stopped the run (e.g. swarm estop, launcher)", max_length=200)
    reason: str = _wire("str", "why, for the logs")
    robots: tuple[int, ...] = _wire("id", "optional: the robots to stop (a lost robot); [] = every robot of the run",
                                    default=(), shape=(None,))

    def applies_to(self, robot: int) -> bool:
        """Whether robot ``robot`` must stop."""
        return not self.robots or robot in self.robots


ESTOP_ACKERS = ("agent", "link")


@dataclass(frozen=True, kw_only=True)
class EstopAck(Message):
    """Agent or link -> whoever stopped the run: it acted on the ``EmergencyStop`` stamped ``stop_stamp_ns``
    (an agent: forwarded it to its robot; a link: sent ESTOP on its port to ``robots``)."""

    TYPE: ClassVar[str] = "EstopAck"
    LEAF: ClassVar[str] = "ack"

    stop_stamp_ns: int = _wire("int", "stamp_ns of the EmergencyStop acknowledged", unit="ns")
    by: str = _wire("str", "agent or link", choices=ESTOP_ACKERS)
    name: str = _wire("str", "the agent's robot id, or the link's port name", max_length=64)
    robots: tuple[int, ...] = _wire("id", "the robots it stopped", shape=(None,))


ROBOT_EVENTS = ("lost", "rejoined")


@dataclass(frozen=True, kw_only=True)
class RobotEvent(Message):
    """Coordinator -> all: robot ``robot`` was lost (dropped from the run, sent an emergency stop) or rejoined it."""

    TYPE: ClassVar[str] = "RobotEvent"
    LEAF: ClassVar[str] = "event"

    robot: int = _wire("id", "the robot")
    kind: str = _wire("str", "lost or rejoined", choices=ROBOT_EVENTS)
    reason: str = _wire("str", "why (lost: liveliness token gone, no answer, refused ...)")


@dataclass(frozen=True, kw_only=True)
class ContactMessage(Message):
    """Coordinator -> recorder, tools (simulation only): the true bodies of robots ``a`` < ``b`` touched during ``step``
    (docs/bodies.md): their centres came ``distance_m`` apart, less than two radii ``radius_m``."""

    TYPE: ClassVar[str] = "ContactMessage"
    LEAF: ClassVar[str] = "contact"

    config: int = _wire("int", "desired configuration being reached: k for C_dk (1-based)")
    a: int = _wire("id", "the robot with the smaller id")
    b: int = _wire("id", "the other robot")
    distance_m: float = _wire("float", "closest distance of the true centres during the step", unit="m", minimum=0.0)
    radius_m: float = _wire("float", "body radius of the run", unit="m", minimum=0.0)
    point: tuple[float, ...] = _wire("float", "[x, y] midway between the centres at their closest", unit="m", shape=(2,))


PHYSICS_EVENTS = ("poses", "contact", "stuck")


@dataclass(frozen=True, kw_only=True)
class PhysicsEvent(Message):
    """The physical world's host -> recorder, tools (``--world physics``, docs/physics.md): what the world did in ``step``.

    ``poses``: the true poses of every robot once the step's motions are over and the world is still; ``contact``: robots
    ``robots`` = [a, b] touched (from ``time_s``, for ``duration_s``; ``ongoing`` if still touching when reported);
    ``stuck``: robot ``robots`` = [r] covered ``achieved_m`` of a drive of ``commanded_m``."""

    TYPE: ClassVar[str] = "PhysicsEvent"
    LEAF: ClassVar[str] = "physics"
    MAX_BYTES: ClassVar[int] = SWARM_BYTES

    kind: str = _wire("str", "poses, contact or stuck", choices=PHYSICS_EVENTS)
    time_s: float = _wire("float", "world time of the event (poses: when the world came to rest; contact: first touch)", unit="s",
                          minimum=0.0)
    robots: tuple[int, ...] = _wire("id", "poses: every robot; contact: the two robots, smaller id first; stuck: the robot",
                                    shape=("n",))
    poses: tuple[tuple[float, ...], ...] = _wire("float", "true [x, y, heading] of each of robots at time_s (poses, stuck) "
                                                          "or at the report (contact)", unit="m, m, rad", shape=("n", 3))
    point: tuple[float, ...] = _wire("float", "contact: [x, y] of the first touch; else []", unit="m", shape=(None,), default=())
    duration_s: float = _wire("float", "contact: how long the bodies touched (until the report if ongoing); else 0", unit="s",
                              minimum=0.0, default=0.0)
    ongoing: int = _wire("int", "contact: 1 if the bodies still touched when it was reported, else 0", maximum=1, default=0)
    impulse_n_s: float = _wire("float", "contact: normal impulse exchanged; else 0", unit="N s", minimum=0.0, default=0.0)
    commanded_m: float = _wire("float", "stuck: the distance the wheels rolled; else 0", unit="m", minimum=0.0, default=0.0)
    achieved_m: float = _wire("float", "stuck: the distance the body moved; else 0", unit="m", minimum=0.0, default=0.0)

    def _check(self) -> None:
        want = {"contact": 2, "stuck": 1}.get(self.kind)
        if want is not None and len(self.robots) != want:
            raise MessageError("PhysicsEvent.robots", f"a {self.kind} names {want} robot(s), got {len(self.robots)}", "size")
        if self.kind == "contact" and len(self.point) != 2:
            raise MessageError("PhysicsEvent.point", f"a contact has an [x, y] point, got {len(self.point)} values", "size")


@dataclass(frozen=True, kw_only=True)
class Checkpoint(Message):
    """Coordinator -> standby coordinators, recorder: the run's state after ``step``, from which another
    coordinator continues the run (docs/failure-model.md). Published after the initial estimate and every step."""

    TYPE: ClassVar[str] = "Checkpoint"
    LEAF: ClassVar[str] = "checkpoint"
    MAX_BYTES: ClassVar[int] = SWARM_BYTES  # the whole run's records: as large as Zenoh's transport lets through

    epoch: int = _wire("int", "the epoch of the coordinator that wrote it")
    config: int = _wire("int", "desired configuration in progress: k for C_dk (1-based); its plan is in state")
    group: int = _wire("int", "the next group of that configuration's plan to move (0-based; = its group count when "
                              "the configuration is done, 0 before it is planned)")
    selector_calls: int = _wire("int", "the anchor selection's random state: searches made so far (AnchorSelector.calls)")
    lost: tuple[int, ...] = _wire("id", "robots lost so far", shape=(None,))
    state: str = _wire("str", "the executor's state as JSON: estimate with covariance, plan, lost robots, the records "
                              "of the steps and configurations done (coordinator.checkpoint)", max_length=MAX_MESSAGE_BYTES)


MESSAGE_TYPES: tuple[type[Message], ...] = (
    MotionCommand,
    ObserveRequest,
    Status,
    ObservationReport,
    PlanMessage,
    EstimateMessage,
    TruthMessage,
    TruthSetMessage,
    LinkRequest,
    LinkReply,
    LinkStats,
    EmergencyStop,
    EstopAck,
    RobotEvent,
    ContactMessage,
    Checkpoint,
    PhysicsEvent,
)
_BY_TYPE = {cls.TYPE: cls for cls in MESSAGE_TYPES}
_BY_LEAF = {cls.LEAF: cls for cls in MESSAGE_TYPES}
M = TypeVar("M", bound=Message)


def message_key(msg: Message) -> str:
    """The key ``msg`` is published on (runtime.wire.keys)."""
    if msg.LEAF in ROBOT_LEAVES:
        return robot_key(msg.run, msg.robot, msg.LEAF)  # type: ignore[attr-defined]
    if msg.LEAF in COORD_LEAVES:
        return coord_key(msg.run, msg.LEAF)
    if isinstance(msg, TruthSetMessage):
        return truths_key(msg.run)
    if isinstance(msg, LinkStats):
        return link_stats_key(msg.run, msg.port)
    if isinstance(msg, EmergencyStop):
        return estop_key(msg.run)
    if isinstance(msg, EstopAck):
        return estop_ack_key(msg.run)
    if isinstance(msg, ContactMessage):
        return contact_key(msg.run)
    if isinstance(msg, PhysicsEvent):
        return physics_key(msg.run)
    return truth_key(msg.run, msg.robot)  # type: ignore[attr-defined]


def type_for_key(key: str) -> type[Message]:
    """The one message type travelling on ``key``; ``KeyspaceError`` for foreign and liveliness keys."""
    leaf = parse_key(key).leaf
    if leaf not in _BY_LEAF:
        raise KeyspaceError(f"key {key!r} is a liveliness token and carries no messages")
    return _BY_LEAF[leaf]


def encode(msg: Message) -> bytes:
    """The msgpack map ``{"type", "v", fields...}`` of a (validated) message."""
    body: dict[str, Any] = {"type": msg.TYPE, "v": msg.VERSION}
    body.update((f.name, getattr(msg, f.name)) for f in _fields(type(msg)))
    return cast(bytes, msgpack.packb(body))  # msgpack ships no types


def _unpack(data: Any, max_bytes: int = MAX_MESSAGE_BYTES) -> Any:
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise MessageError("message", f"is a {type(data).__name__}, expected bytes", "undecodable")
    size = memoryview(data).nbytes
    if size > max_bytes:
        raise MessageError("message", f"{size} bytes, at most {max_bytes} allowed", "size")
    limit = 4 * MAX_TEXT
    try:
        return msgpack.unpackb(
            data, raw=False, max_str_len=MAX_MESSAGE_BYTES, max_bin_len=limit, max_ext_len=limit, max_array_len=MAX_ITEMS, max_map_len=64
        )
    except Exception as e:  # noqa: BLE001 - msgpack raises several exception types for bad input; none may escape
        raise MessageError("message", f"not valid msgpack ({type(e).__name__}: {_show(str(e))})", "undecodable") from None


def _message_class(raw: Any, expected: type[Message] | None) -> type[Message]:
    if not isinstance(raw, dict):
        raise MessageError("message", f"is a msgpack {type(raw).__name__}, expected a map", "not-a-map")
    if "type" not in raw:
        raise MessageError("message.type", "missing", "missing-field")
    name = raw["type"]
    if not isinstance(name, str):
        raise MessageError("message.type", f"{_show(name)} is a {type(name).__name__}, expected a string", "wrong-type")
    if name not in _BY_TYPE:
        raise MessageError("message.type", f"{_show(name)} is unknown (known: {', '.join(_BY_TYPE)})", "unknown-type")
    cls = _BY_TYPE[name]
    if expected is not None and cls is not expected:
        raise MessageError("message.type", f"{name} where {expected.TYPE} was expected", "unexpected-type")
    if "v" not in raw:
        raise MessageError(f"{name}.v", "missing", "missing-field")
    v = raw["v"]
    if isinstance(v, bool) or not isinstance(v, int):
        raise MessageError(f"{name}.v", f"{_show(v)} is a {type(v).__name__}, expected an integer", "wrong-type")
    if v != cls.VERSION:
        raise MessageError(f"{name}.v", f"version {v} is not supported (this decoder reads version {cls.VERSION})", "version")
    return cls


def _readable_header(cls: type[Message], raw: dict[str, Any]) -> dict[str, Any]:
    header: dict[str, Any] = {"type": cls.TYPE}
    for f in fields(cls):
        if f.name in ("run", "step", "robot", "cmd_id") and f.name in raw:
            try:
                header[f.name] = _convert(raw[f.name], f.metadata["wire"], f.name, {})
            except MessageError:
                pass
    return header


def _check_known(msg: Message, known: frozenset[int] | set[int]) -> None:
    for f in _fields(type(msg)):
        wire = f.metadata["wire"]
        if wire.kind == "id":
            value, depth = getattr(msg, f.name), len(wire.shape)
            if (depth == 0 and value in known) or (depth == 1 and known.issuperset(value)):
                continue  # the common case, checked in C; the walk below names the first stranger
            for path, robot in _leaves(value, f"{msg.TYPE}.{f.name}", depth):
                if robot not in known:
                    raise MessageError(path, f"robot {robot} is not one of the run's {len(known)} robots", "unknown-id")


@overload
def decode(data: bytes, expected: type[M], known_ids: Collection[int] | None = None, *, key: str | None = None) -> M: ...


@overload
def decode(data: bytes, expected: None = None, known_ids: Collection[int] | None = None, *, key: str | None = None) -> Message: ...


def decode(
    data: bytes, expected: type[Message] | None = None, known_ids: Collection[int] | None = None, *, key: str | None = None
) -> Message:
    """The message in ``data``, fully validated; any problem raises ``MessageError``.

    ``expected``: the type required. ``known_ids``: every robot id must be one of them.
    ``key``: the key the data arrived on; the message must belong there (type, run,
    robot) and, without ``expected``, its type is the key's type. With a key, the
    error's ``header`` is kept only if its run and robot match the key.
    """
    parsed = None
    if key is not None:
        try:
            parsed = parse_key(key)
            expected = expected or type_for_key(key)
        except KeyspaceError as e:
            raise MessageError("key", str(e), "wrong-key") from None
    raw = _unpack(data, MAX_MESSAGE_BYTES if expected is None else expected.MAX_BYTES)
    try:
        cls = _message_class(raw, expected)
        if memoryview(data).nbytes > cls.MAX_BYTES:
            raise MessageError("message", f"{memoryview(data).nbytes} bytes, at most {cls.MAX_BYTES} allowed for {cls.TYPE}", "size")
    except MessageError as e:
        if e.reason == "version" and (expected is None or raw.get("type") == expected.TYPE):
            e.header = _readable_header(_BY_TYPE[raw["type"]], raw)
            if parsed is not None and (e.header.get("run"), e.header.get("robot")) != (parsed.run, parsed.robot):
                e.header = {"type": raw["type"]}
        raise
    try:
        for f in _fields(cls):
            if f.name not in raw and not f.metadata["wire"].optional:
                raise MessageError(f"{cls.TYPE}.{f.name}", "missing", "missing-field")
        msg = cls(**{f.name: raw[f.name] for f in _fields(cls) if f.name in raw})
        if known_ids is not None:
            known = known_ids if isinstance(known_ids, (set, frozenset)) else frozenset(int(i) for i in known_ids)
            _check_known(msg, known)
        if key is not None and message_key(msg) != key:
            raise MessageError("key", f"arrived on {key!r}, belongs on {message_key(msg)!r}", "wrong-key")
    except MessageError as e:
        e.header = _readable_header(cls, raw)
        if parsed is not None and (e.header.get("run"), e.header.get("robot")) != (parsed.run, parsed.robot):
            e.header = {"type": cls.TYPE}  # not for this key: nobody may answer on its behalf
        raise
    return msg


def refusal_status(error: MessageError, stamp_ns: int | None = None) -> Status | None:
    """The refusal an agent publishes for a MotionCommand it could not decode, if its header says whose it is."""
    header = error.header
    if header.get("type") != MotionCommand.TYPE or not {"run", "step", "robot"} <= header.keys():
        return None
    stamp = time.time_ns() if stamp_ns is None else stamp_ns
    reason = str(error)[:MAX_TEXT]
    return Status(run=header["run"], step=header["step"], stamp_ns=stamp, robot=header["robot"], state="refused", reason=reason,
                  cmd_id=header.get("cmd_id", 0))


@dataclass(frozen=True)
class CommandLimits:
    """What an agent executes: |turn| <= ``max_turn_rad`` (rad), 0 <= drive <= ``max_drive_m`` (m), and,
    with ``workspace`` = (x_min, y_min, x_max, y_max) (m), an end position inside it predicted from the
    command's ``start_pose``."""

    max_drive_m: float = 1.0
    max_turn_rad: float = math.pi
    workspace: tuple[float, float, float, float] | None = None

    def __post_init__(self) -> None:
        for name in ("max_drive_m", "max_turn_rad"):
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
                raise SwarmInputError(f"CommandLimits.{name} must be a finite number > 0, got {value!r}")
        if self.workspace is not None:
            w = tuple(float(v) for v in self.workspace)
            if len(w) != 4 or not all(math.isfinite(v) for v in w) or not (w[0] < w[2] and w[1] < w[3]):
                raise SwarmInputError(f"CommandLimits.workspace must be finite (x_min, y_min, x_max, y_max) with min < max, got {self.workspace!r}")
            object.__setattr__(self, "workspace", w)

    def refusal(self, cmd: MotionCommand | LinkRequest) -> str | None:
        """Why ``cmd`` must be refused, or None when it is within the limits.

        The workspace is checked from ``cmd.start_pose`` (the coordinator's estimate of the
        robot before the move); a command without it cannot be checked against the workspace.
        """
        if abs(cmd.turn_rad) > self.max_turn_rad:
            return f"turn_rad {cmd.turn_rad:.6g} exceeds the limit |turn| <= {self.max_turn_rad:.6g} rad"
        if cmd.drive_m < 0:
            return f"drive_m {cmd.drive_m:.6g} is negative"
        if cmd.drive_m > self.max_drive_m:
            return f"drive_m {cmd.drive_m:.6g} exceeds the limit {self.max_drive_m:.6g} m"
        if self.workspace is not None and cmd.start_pose:
            x, y, heading = cmd.start_pose
            end_x = x + cmd.drive_m * math.cos(heading + cmd.turn_rad)
            end_y = y + cmd.drive_m * math.sin(heading + cmd.turn_rad)
            x0, y0, x1, y1 = self.workspace
            if not (x0 <= end_x <= x1 and y0 <= end_y <= y1):
                return (f"the move would end at ({end_x:.3f}, {end_y:.3f}) m, outside the workspace "
                        f"x in [{x0:g}, {x1:g}], y in [{y0:g}, {y1:g}]")
        return None


class DropCounter:
    """Dropped messages counted by (source, reason), logged at a bounded rate.

    ``source`` is the key the message arrived on (or its type); ``reason`` one of
    ``REASONS``. The first drop on a source is logged at once; later ones at most once per
    ``log_every_s`` per source, as one line with the count since the last line (a flood of
    50,000 bad messages is a handful of lines, not 50,000). Thread-safe: Zenoh callbacks may
    run concurrently.
    """

    LOG_EVERY_S = 5.0
    MAX_SOURCES = 1024  # distinct sources counted one by one; beyond, drops count under "other keys"

    def __init__(self, logger: logging.Logger = _log, log_every_s: float = LOG_EVERY_S) -> None:
        self._logger = logger
        self.log_every_s = float(log_every_s)
        self._counts: dict[tuple[str, str], int] = {}
        self._quiet: dict[str, tuple[float, int]] = {}  # source -> (last line's time, drops since)
        self._lock = threading.Lock()

    def drop(self, source: str, error: MessageError) -> None:
        now = time.monotonic()
        with self._lock:
            if source not in self._quiet and len(self._quiet) >= self.MAX_SOURCES:
                source = "other keys"  # forged keys must not grow the tables without bound
            self._counts[source, error.reason] = self._counts.get((source, error.reason), 0) + 1
            last, since = self._quiet.get(source, (-math.inf, 0))
            if now - last < self.log_every_s:
                self._quiet[source] = (last, since + 1)
                return
            self._quiet[source] = (now, 0)
        more = f" (and {since} more on this key since the last line)" if since else ""
        self._logger.warning("dropped message on %s (%s): %s%s", source, error.reason, error, more)

    @property
    def total(self) -> int:
        with self._lock:
            return sum(self._counts.values())

    def snapshot(self) -> dict[str, dict[str, int]]:
        """Counts so far as ``{source: {reason: count}}``."""
        out: dict[str, dict[str, int]] = {}
        with self._lock:
            for (source, reason), count in sorted(self._counts.items()):
                out.setdefault(source, {})[reason] = count
        return out


@overload
def decode_or_drop(
    data: bytes, counter: DropCounter, key: str, expected: type[M], known_ids: Collection[int] | None = None
) -> M | None: ...


@overload
def decode_or_drop(
    data: bytes, counter: DropCounter, key: str, expected: None = None, known_ids: Collection[int] | None = None
) -> Message | None: ...


def decode_or_drop(
    data: bytes, counter: DropCounter, key: str, expected: type[Message] | None = None, known_ids: Collection[int] | None = None
) -> Message | None:
    """``decode(data, expected, known_ids, key=key)``, or None after counting and logging the drop."""
    try:
        return decode(data, expected, known_ids, key=key)
    except MessageError as e:
        counter.drop(key, e)
        return None


def observations_from_reports(reports: Iterable[ObservationReport]) -> Observations:
    """All reports' observations as one ``Observations`` (rows in report order)."""
    reports = list(reports)
    if not reports:
        return Observations.empty()
    return Observations(
        np.concatenate([np.full(len(r.observed), r.robot, np.int64) for r in reports]),
        np.concatenate([np.array(r.observed, np.int64) for r in reports]),
        np.concatenate([np.array(r.ranges, float) for r in reports]),
        np.concatenate([np.array(r.bearings, float) for r in reports]),
    )


def _field_schema(wire: Wire) -> dict[str, Any]:
    if wire.kind == "str":
        node: dict[str, Any] = {"type": "string", "maxLength": wire.max_length}
        if wire.choices:
            node["enum"] = list(wire.choices)
        if wire.pattern:
            node["pattern"] = f"^{wire.pattern}$"
    elif wire.kind == "float":
        node = {"type": "number"}
        if wire.minimum is not None:
            node["minimum"] = wire.minimum - wire.slack
        if wire.maximum is not None:
            node["maximum"] = wire.maximum + wire.slack
    else:
        node = {"type": "integer", "minimum": 0, "maximum": MAX_INT}
    for dim in reversed(wire.shape):
        sizes = {"minItems": dim, "maxItems": dim} if isinstance(dim, int) else {"maxItems": MAX_ITEMS}
        node = {"type": "array", "items": node, **sizes}
    shared = [d for d in wire.shape if isinstance(d, str)]
    node["description"] = wire.doc + (f" [{wire.unit}]" if wire.unit else "") + (
        f" (length {shared[0]}: equal for every length-{shared[0]} field)" if shared else ""
    )
    return node


def json_schema(message_type: type[Message]) -> dict[str, Any]:
    """JSON schema (draft 2020-12) of the encoded map of ``message_type``, from its field specs.

    Unknown extra fields are allowed (and ignored by ``decode``): see the versioning rule.
    """
    properties: dict[str, Any] = {
        "type": {"const": message_type.TYPE, "description": "message type"},
        "v": {"const": message_type.VERSION, "description": "major schema version"},
    }
    required = list(properties)
    for f in fields(message_type):
        properties[f.name] = _field_schema(f.metadata["wire"])
        if not f.metadata["wire"].optional:
            required.append(f.name)
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": message_type.TYPE,
        "description": (message_type.__doc__ or "").strip(),
        "type": "object",
        "properties": properties,
        "required": required,
        "additionalProperties": True,
    }
