"""Message layer: keys, encoding, validation, fuzzing, schemas, drop counting, docs/protocol.md."""

from __future__ import annotations

import copy
import json
import logging
import math
import re
import time
from dataclasses import fields
from pathlib import Path

import msgpack
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

import runtime.wire.messages as messages
from runtime.errors import SwarmInputError
from runtime.models.state import SwarmEstimate
from runtime.wire.keys import (
    KeyspaceError,
    ParsedKey,
    alive_key,
    alive_wildcard,
    coord_alive_key,
    coord_key,
    estop_ack_key,
    parse_key,
    robot_key,
    robot_wildcard,
    run_wildcard,
    truth_key,
    truth_wildcard,
    validate_run,
)
from runtime.wire.messages import (
    MAX_ITEMS,
    MESSAGE_TYPES,
    CommandLimits,
    ContactMessage,
    DropCounter,
    EmergencyStop,
    EstimateMessage,
    EstopAck,
    LinkReply,
    LinkRequest,
    LinkStats,
    Message,
    MessageError,
    MotionCommand,
    ObservationReport,
    ObserveRequest,
    PlanMessage,
    RobotEvent,
    Status,
    TruthMessage,
    TruthSetMessage,
    decode,
    decode_or_drop,
    encode,
    json_schema,
    message_key,
    observations_from_reports,
    refusal_status,
    type_for_key,
)
from runtime.wire.rate_limit import RateLimit

PROTOCOL_MD = Path(__file__).resolve().parents[2] / "docs" / "protocol.md"
STAMP = 1_700_000_000_123_456_789


def samples() -> list[Message]:
    """One valid message of every type, built from numpy inputs where a producer would use them."""
    head = {"run": "r1", "step": 7, "stamp_ns": STAMP}
    return [
        MotionCommand(**head, robot=np.int64(3), config=2, turn_rad=np.float64(0.5), drive_m=0.12, start_pose=np.array([0.1, 0.2, 1.5]),
                      cmd_id=np.int64(2**62 + 5)),
        ObserveRequest(**head, robot=3),
        Status(**head, robot=3, state="refused", reason="drive_m 2 exceeds the limit 1 m", cmd_id=2**62 + 5),
        ObservationReport(
            **head, robot=3, observed=np.array([1, 4, 9]), ranges=np.array([0.2, 0.31, 0.0]), bearings=[0.1, -math.pi, 3.0]
        ),
        PlanMessage(**head, config=2, n_anchors=3, groups=[np.array([3, 1]), [4, 9]]),
        EstimateMessage.from_estimate(
            SwarmEstimate.isotropic([1, 3, 4, 9], np.arange(12.0).reshape(4, 3) / 10, 0.01, 0.02), run="r1", step=7, stamp_ns=STAMP
        ),
        TruthMessage(**head, robot=3, pose=np.array([0.5, -0.25, 1.0])),
        TruthSetMessage(**head, ids=[1, 3], poses=np.array([[0.5, -0.25, 1.0], [0.1, 0.2, -3.0]])),
        LinkRequest(**head, robot=3, kind="command", turn_rad=0.5, drive_m=0.1, start_pose=[0.1, 0.2, 1.5]),
        LinkReply(**head, robot=3, kind="observation", reason="", observed=[1, 4], ranges=[0.2, 0.31], bearings=[0.1, -2.0]),
        LinkStats(**head, port="radio0", robots=[1, 3], frames_sent=10, frames_received=9, retransmissions=1, crc_errors=2,
                  length_errors=0, skipped_bytes=5, timeouts=0, rtt_ms_median=1.5, rtt_ms_p90=2.0, rtt_ms_max=3.25, lost=[4]),
        EmergencyStop(**head, source="swarm estop", reason="operator pressed stop", robots=[4]),
        EstopAck(**head, stop_stamp_ns=STAMP - 1, by="link", name="radio0", robots=[1, 3]),
        RobotEvent(**head, robot=4, kind="lost", reason="liveliness token gone"),
        ContactMessage(**head, config=2, a=3, b=4, distance_m=0.0185, radius_m=0.011, point=[0.25, -0.5]),
    ]


SAMPLES = {type(m).__name__: m for m in samples()}
KNOWN = {1, 3, 4, 9}


def raw_map(msg: Message) -> dict:
    return msgpack.unpackb(encode(msg))


def decode_map(raw: dict, **kw) -> Message:
    return decode(msgpack.packb(raw), **kw)


def reject(raw: dict, where: str, reason: str, **kw) -> MessageError:
    with pytest.raises(MessageError) as info:
        decode_map(raw, **kw)
    assert info.value.where == where, str(info.value)
    assert info.value.reason == reason, str(info.value)
    assert str(info.value).startswith(where + ": ")
    return info.value


def leaf_path(value) -> list[int]:
    """Indices of the first scalar inside nested lists."""
    path = []
    while isinstance(value, list):
        path.append(0)
        value = value[0]
    return path


def with_leaf(raw: dict, name: str, bad) -> tuple[dict, str]:
    """``raw`` with the first scalar of field ``name`` replaced by ``bad``, and that scalar's path."""
    raw = copy.deepcopy(raw)
    path = leaf_path(raw[name])
    if not path:
        raw[name] = bad
    else:
        target = raw[name]
        for i in path[:-1]:
            target = target[i]
        target[path[-1]] = bad
    return raw, name + "".join(f"[{i}]" for i in path)


def wire_of(cls: type[Message], name: str):
    return next(f.metadata["wire"] for f in fields(cls) if f.name == name)


def field_cases(kinds: set[str]) -> list[tuple[str, str]]:
    return [(t, f.name) for t, m in SAMPLES.items() for f in fields(m) if f.metadata["wire"].kind in kinds]


# ---------------------------------------------------------------- round trips


@pytest.mark.parametrize("name", SAMPLES)
def test_round_trip_every_type(name):
    msg = SAMPLES[name]
    data = encode(msg)
    assert decode(data) == msg
    assert decode(data, type(msg), KNOWN, key=message_key(msg)) == msg
    raw = msgpack.unpackb(data)
    assert list(raw)[:2] == ["type", "v"] and raw["type"] == name and raw["v"] == 1
    assert raw["run"] == "r1" and raw["step"] == 7 and raw["stamp_ns"] == STAMP


def test_numpy_inputs_become_plain_python_values():
    cmd = MotionCommand(run="r", step=np.uint8(1), stamp_ns=1, robot=np.int32(2), config=1, turn_rad=np.float32(0.5), drive_m=1)
    assert type(cmd.step) is int and type(cmd.robot) is int
    assert type(cmd.turn_rad) is float and type(cmd.drive_m) is float and cmd.drive_m == 1.0
    report = SAMPLES["ObservationReport"]
    assert report.observed == (1, 4, 9) and all(type(v) is float for v in report.ranges)
    assert decode(encode(report)) == report


def test_default_stamp_is_now():
    before = time.time_ns()
    assert before <= ObserveRequest(run="r", step=0, robot=1).stamp_ns <= time.time_ns()


def test_ints_are_accepted_for_floats_on_the_wire():
    raw = raw_map(SAMPLES["TruthMessage"])
    raw["pose"] = [1, 2, 0]
    assert decode_map(raw).pose == (1.0, 2.0, 0.0)


@pytest.mark.parametrize("n", [1, 5])
def test_swarm_estimate_round_trip(n):
    rng = np.random.default_rng(n)
    a = rng.normal(size=(n, 3, 3))
    est = SwarmEstimate(np.arange(n) * 3 + 2, rng.normal(size=(n, 3)), a @ np.swapaxes(a, 1, 2))
    msg = decode(encode(EstimateMessage.from_estimate(est, run="r", step=4)), EstimateMessage)
    back = msg.to_estimate()
    np.testing.assert_array_equal(back.ids, est.ids)
    np.testing.assert_array_equal(back.poses, est.poses)
    np.testing.assert_array_equal(back.cov, est.cov)


finite = st.floats(allow_nan=False, allow_infinity=False)


@given(
    st.lists(
        st.tuples(st.integers(0, 2**63 - 1), st.floats(0, 1e9), st.floats(-math.pi, math.pi)),
        max_size=30,
    ),
    st.integers(0, 2**63 - 1),
)
def test_observation_report_round_trip_property(rows, step):
    rows = [r for r in rows if r[0] != 5]
    msg = ObservationReport(
        run="a.b-c_1",
        step=step,
        robot=5,
        observed=[r[0] for r in rows],
        ranges=[r[1] for r in rows],
        bearings=[r[2] for r in rows],
    )
    assert decode(encode(msg)) == msg


@given(st.lists(st.tuples(finite, finite, finite), max_size=20))
def test_truth_and_motion_round_trip_property(values):
    for i, (x, y, h) in enumerate(values):
        truth = TruthMessage(run="r", step=i, robot=i, pose=[x, y, h])
        cmd = MotionCommand(run="r", step=i, robot=i, config=1, turn_rad=x, drive_m=y)
        assert decode(encode(truth)) == truth and decode(encode(cmd)) == cmd


def test_observations_from_reports():
    second = ObservationReport(run="r1", step=7, robot=4, observed=[3], ranges=[0.3], bearings=[1.0])
    obs = observations_from_reports([SAMPLES["ObservationReport"], second])
    assert obs.observer.tolist() == [3, 3, 3, 4] and obs.observed.tolist() == [1, 4, 9, 3]
    np.testing.assert_array_equal(obs.range_m, [0.2, 0.31, 0.0, 0.3])
    assert len(observations_from_reports([])) == 0


# ---------------------------------------------------------------- validation


@pytest.mark.parametrize("name,field", [(t, f.name) for t, m in SAMPLES.items() for f in fields(m)
                                        if not f.metadata["wire"].optional])
def test_missing_field(name, field):
    raw = raw_map(SAMPLES[name])
    del raw[field]
    reject(raw, f"{name}.{field}", "missing-field")


def test_optional_field_may_be_missing_and_is_checked():
    raw = raw_map(SAMPLES["MotionCommand"])
    assert raw["start_pose"] == [0.1, 0.2, 1.5]
    del raw["start_pose"]  # a message from before the field existed
    assert decode_map(raw).start_pose == ()
    assert "start_pose" not in json_schema(MotionCommand)["required"]
    reject({**raw, "start_pose": [1.0, 2.0]}, "MotionCommand.start_pose", "size")


@pytest.mark.parametrize("name,field", field_cases({"int", "id"}))
def test_bool_for_int(name, field):
    raw, path = with_leaf(raw_map(SAMPLES[name]), field, True)
    err = reject(raw, f"{name}.{path}", "wrong-type")
    assert "bool" in str(err) and "integer" in str(err)


@pytest.mark.parametrize("name,field", field_cases({"int", "id"}))
def test_float_for_int_and_negative_int(name, field):
    raw, path = with_leaf(raw_map(SAMPLES[name]), field, 1.0)
    reject(raw, f"{name}.{path}", "wrong-type")
    raw, path = with_leaf(raw_map(SAMPLES[name]), field, -1)
    reject(raw, f"{name}.{path}", "out-of-range")
    raw, path = with_leaf(raw_map(SAMPLES[name]), field, 2**64 - 1)
    reject(raw, f"{name}.{path}", "out-of-range")


@pytest.mark.parametrize("name,field", field_cases({"float"}))
@pytest.mark.parametrize("bad,reason", [("1.0", "wrong-type"), (True, "wrong-type"), (None, "wrong-type")])
def test_wrong_type_for_float(name, field, bad, reason):
    raw, path = with_leaf(raw_map(SAMPLES[name]), field, bad)
    reject(raw, f"{name}.{path}", reason)


@pytest.mark.parametrize("name,field", field_cases({"float"}))
@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_non_finite(name, field, bad):
    raw, path = with_leaf(raw_map(SAMPLES[name]), field, bad)
    err = reject(raw, f"{name}.{path}", "non-finite")
    assert "not finite" in str(err)


@pytest.mark.parametrize("name,field", field_cases({"str"}))
def test_wrong_type_for_str(name, field):
    raw, path = with_leaf(raw_map(SAMPLES[name]), field, 5)
    reject(raw, f"{name}.{path}", "wrong-type")


def test_negative_range_is_named():
    raw = raw_map(SAMPLES["ObservationReport"])
    raw["ranges"][2] = -0.2
    err = reject(raw, "ObservationReport.ranges[2]", "out-of-range")
    assert str(err) == "ObservationReport.ranges[2]: -0.2 is negative"


@pytest.mark.parametrize("bearing,ok", [(math.pi, True), (-math.pi - 1e-10, True), (math.pi + 1e-6, False), (-4.0, False)])
def test_bearing_range(bearing, ok):
    raw = raw_map(SAMPLES["ObservationReport"])
    raw["bearings"][1] = bearing
    if ok:
        assert decode_map(raw).bearings[1] == bearing
    else:
        assert "outside [-3.14159" in str(reject(raw, "ObservationReport.bearings[1]", "out-of-range"))


@pytest.mark.parametrize(
    "name,field,value,where",
    [
        ("ObservationReport", "ranges", [0.1, 0.2], "ObservationReport.ranges"),
        ("ObservationReport", "bearings", [0.1, 0.2, 0.3, 0.4], "ObservationReport.bearings"),
        ("ObservationReport", "observed", [1, 4], "ObservationReport.ranges"),
        ("EstimateMessage", "poses", [[0.0, 0.0, 0.0]] * 3, "EstimateMessage.poses"),
        ("EstimateMessage", "poses", [[0.0, 0.0]] * 4, "EstimateMessage.poses[0]"),
        ("EstimateMessage", "cov", [np.eye(3).tolist()] * 5, "EstimateMessage.cov"),
        ("EstimateMessage", "cov", [np.eye(2).tolist()] * 4, "EstimateMessage.cov[0]"),
        ("EstimateMessage", "cov", [[[0.0, 0.0, 0.0]] * 3] * 3 + [[[0.0] * 4] * 3], "EstimateMessage.cov[3][0]"),
        ("TruthMessage", "pose", [0.0, 0.0, 0.0, 0.0], "TruthMessage.pose"),
    ],
)
def test_sizes(name, field, value, where):
    raw = raw_map(SAMPLES[name])
    raw[field] = value
    reject(raw, where, "size")


def test_list_where_scalar_and_scalar_where_list():
    raw = raw_map(SAMPLES["MotionCommand"])
    raw["turn_rad"] = [0.1]
    reject(raw, "MotionCommand.turn_rad", "wrong-type")
    raw = raw_map(SAMPLES["PlanMessage"])
    raw["groups"] = [3, 1]
    reject(raw, "PlanMessage.groups[0]", "wrong-type")


def test_absurd_sizes_are_refused():
    with pytest.raises(MessageError, match=r"ObservationReport.observed: 100001 items, at most 100000"):
        ObservationReport(run="r", step=0, robot=0, observed=np.arange(1, MAX_ITEMS + 2), ranges=[], bearings=[])
    raw = raw_map(SAMPLES["ObservationReport"])
    raw["observed"] = list(range(1, MAX_ITEMS + 2))
    with pytest.raises(MessageError, match="max_array_len"):
        decode_map(raw)
    raw = raw_map(SAMPLES["Status"])
    raw["reason"] = "x" * 2001
    reject(raw, "Status.reason", "size")


def test_unknown_type_version_and_expected_type():
    raw = raw_map(SAMPLES["MotionCommand"])
    reject({**raw, "type": "Teleport"}, "message.type", "unknown-type")
    reject({**raw, "type": b"MotionCommand"}, "message.type", "wrong-type")
    reject({k: v for k, v in raw.items() if k != "type"}, "message.type", "missing-field")
    err = reject({**raw, "v": 2}, "MotionCommand.v", "version")
    assert "version 2 is not supported (this decoder reads version 1)" in str(err)
    reject({**raw, "v": True}, "MotionCommand.v", "wrong-type")
    reject({k: v for k, v in raw.items() if k != "v"}, "MotionCommand.v", "missing-field")
    reject(raw, "message.type", "unexpected-type", expected=Status)


def test_unknown_extra_fields_are_ignored():
    raw = raw_map(SAMPLES["Status"])
    assert decode_map({**raw, "note": [1, 2]}) == SAMPLES["Status"]


@pytest.mark.parametrize("run", ["", "a/b", "a*", "$x", "#", "a?", "a b", "a\tb", ".hidden", "-x", "é", "x" * 65, 3])
def test_bad_run_ids(run):
    with pytest.raises(KeyspaceError):
        validate_run(run)
    with pytest.raises(MessageError, match=r"Status.run: "):
        Status(run=run, step=0, robot=1, state="done", reason="")
    raw = raw_map(SAMPLES["Status"])
    raw["run"] = run
    reject(raw, "Status.run", "wrong-type" if run == 3 else ("size" if len(run) > 64 else "out-of-range"))


def test_status_rules():
    raw = raw_map(SAMPLES["Status"])
    reject({**raw, "state": "crashed"}, "Status.state", "out-of-range")
    reject({**raw, "reason": ""}, "Status.reason", "invalid")
    reject({**raw, "state": "done"}, "Status.reason", "invalid")
    assert decode_map({**raw, "state": "accepted", "reason": ""}).state == "accepted"


def test_cross_field_rules():
    raw = raw_map(SAMPLES["ObservationReport"])
    raw["observed"][1] = 3
    assert "robot 3 observes itself" in str(reject(raw, "ObservationReport.observed[1]", "invalid"))
    raw = raw_map(SAMPLES["PlanMessage"])
    reject({**raw, "groups": [[3], [1, 3]]}, "PlanMessage.groups[1][1]", "invalid")
    reject({**raw, "groups": [[3], []]}, "PlanMessage.groups[1]", "invalid")
    reject({**raw, "groups": []}, "PlanMessage.groups", "invalid")
    raw = raw_map(SAMPLES["EstimateMessage"])
    reject({**raw, "ids": [], "poses": [], "cov": []}, "EstimateMessage.ids", "invalid")
    raw["ids"][3] = 1
    reject(raw, "EstimateMessage.ids[3]", "invalid")


@pytest.mark.parametrize("name,field", field_cases({"id"}))
def test_unknown_robot_id(name, field):
    raw, path = with_leaf(raw_map(SAMPLES[name]), field, 77)
    err = reject(raw, f"{name}.{path}", "unknown-id", known_ids=KNOWN)
    assert "robot 77 is not one of the run's 4 robots" in str(err)
    assert decode_map(raw, known_ids=np.array(sorted(KNOWN | {77}))) is not None


def test_construction_validates_like_decoding():
    with pytest.raises(MessageError, match=r"^MotionCommand.turn_rad: nan is not finite$"):
        MotionCommand(run="r", step=1, robot=1, config=1, turn_rad=math.nan, drive_m=0.1)
    with pytest.raises(MessageError, match=r"^TruthMessage.pose: 2 items, expected 3$"):
        TruthMessage(run="r", step=1, robot=1, pose=np.zeros(2))
    with pytest.raises(MessageError, match=r"^ObserveRequest.robot: .*True.* is a bool"):
        ObserveRequest(run="r", step=1, robot=np.bool_(True))
    with pytest.raises(MessageError, match="too large"):
        MotionCommand(run="r", step=1, robot=1, config=1, turn_rad=10**400, drive_m=0.1)
    assert isinstance(MessageError("x", "y", "invalid"), SwarmInputError)


# ---------------------------------------------------------------- fuzzing


def only_message_errors(data) -> None:
    try:
        decode(data, known_ids=KNOWN)
    except MessageError:
        pass


@settings(max_examples=400, suppress_health_check=[HealthCheck.too_slow])
@given(st.binary(max_size=300))
def test_fuzz_bytes(data):
    only_message_errors(data)
    only_message_errors(b"\x8a" + data)  # a map header, so decoding goes further


msgpackable = st.recursive(
    st.none()
    | st.booleans()
    | st.integers(-(2**63), 2**64 - 1)
    | st.floats()
    | st.text(max_size=20)
    | st.binary(max_size=20),
    lambda inner: st.lists(inner, max_size=5) | st.dictionaries(st.text(max_size=10), inner, max_size=5),
    max_leaves=20,
)


@settings(max_examples=400, suppress_health_check=[HealthCheck.too_slow])
@given(msgpackable)
def test_fuzz_structures(value):
    only_message_errors(msgpack.packb(value))


@settings(max_examples=600, suppress_health_check=[HealthCheck.too_slow])
@given(st.sampled_from(sorted(SAMPLES)), st.data())
def test_fuzz_fields_of_valid_messages(name, data):
    raw = raw_map(SAMPLES[name])
    field = data.draw(st.sampled_from(sorted(raw)))
    raw[field] = data.draw(msgpackable)
    if data.draw(st.booleans()) and isinstance(SAMPLES[name], ObservationReport):
        raw["ranges"] = data.draw(st.lists(st.floats(), min_size=3, max_size=3))
    only_message_errors(msgpack.packb(raw))


leafy = st.one_of(
    st.floats(), st.integers(-5, 2**64), st.booleans(), st.text(max_size=3),
    st.sampled_from([math.inf, -math.inf, math.nan, math.pi + 2e-9, -0.0, 2**63, np.float32(0.5), np.int64(3), True]),
)
shaped = st.one_of(leafy, st.recursive(leafy, lambda inner: st.lists(inner, max_size=4) | st.tuples(inner, inner, inner), max_leaves=12))


def outcome(cls, values: dict):
    """``cls(**values)``: its fields, or the error's (path, reason)."""
    try:
        msg = cls(**values)
    except MessageError as e:
        return ("error", str(e), e.reason)
    return ("ok", *(repr(getattr(msg, f.name)) for f in fields(cls)))


@settings(max_examples=600, suppress_health_check=[HealthCheck.too_slow])
@given(st.sampled_from(sorted(SAMPLES)), st.data())
def test_the_fast_validation_path_changes_no_outcome(name, data):
    """Construction checks plain fields with compiled predicates and list fields level by level in C before the
    general walk; with those fast paths disabled every message (values mutated with NaN, infinities, bools,
    ints for floats, float32, nested lists of wrong lengths) gives the same fields or the same error."""
    sample = SAMPLES[name]
    cls = type(sample)
    values = {f.name: getattr(sample, f.name) for f in fields(cls)}
    for key in data.draw(st.lists(st.sampled_from(sorted(values)), max_size=3)):
        values[key] = data.draw(shaped)
    fast = outcome(cls, values)
    plan, plain = messages._plan, messages._plain_nested
    try:
        messages._plan = lambda c: tuple((n, w, None) for n, w, _ in plan(c))
        messages._plain_nested = lambda *args: None
        slow = outcome(cls, values)
    finally:
        messages._plan, messages._plain_nested = plan, plain
    assert fast == slow


@pytest.mark.parametrize("name", SAMPLES)
def test_truncated_encodings(name):
    data = encode(SAMPLES[name])
    for cut in range(len(data)):
        with pytest.raises(MessageError) as info:
            decode(data[:cut])
        assert info.value.reason in ("undecodable", "not-a-map")
    with pytest.raises(MessageError, match="extra data"):
        decode(data + b"\x00")


def test_non_bytes_input():
    for value in (None, "text", 5, [1]):
        with pytest.raises(MessageError, match="expected bytes"):
            decode(value)
    assert decode(bytearray(encode(SAMPLES["Status"]))) == decode(memoryview(encode(SAMPLES["Status"])))


# ---------------------------------------------------------------- keys


def test_key_builders_and_parse_round_trip():
    cases = {
        robot_key("r1", 12, "cmd"): ParsedKey("r1", "robot", 12, "cmd"),
        robot_key("r1", 0, "observe"): ParsedKey("r1", "robot", 0, "observe"),
        robot_key("r1", np.int64(3), "status"): ParsedKey("r1", "robot", 3, "status"),
        robot_key("run-2.a_b", 2**63 - 1, "obs"): ParsedKey("run-2.a_b", "robot", 2**63 - 1, "obs"),
        coord_key("r1", "plan"): ParsedKey("r1", "coord", None, "plan"),
        coord_key("r1", "estimate"): ParsedKey("r1", "coord", None, "estimate"),
        truth_key("r1", 7): ParsedKey("r1", "sim", 7, "truth"),
        alive_key("r1", 7): ParsedKey("r1", "alive", 7, "alive"),
        coord_alive_key("r1", 7, 0): ParsedKey("r1", "alive", None, "alive"),
        estop_ack_key("r1"): ParsedKey("r1", "estop", None, "ack"),
    }
    for key, parsed in cases.items():
        assert parse_key(key) == parsed
    assert robot_key("r1", 12, "cmd") == "swarm/r1/robot/12/cmd"
    assert truth_key("r1", 7) == "swarm/r1/sim/truth/7"
    assert alive_key("r1", 7) == "swarm/r1/alive/robot/7"
    assert robot_wildcard("r1", "obs") == "swarm/r1/robot/*/obs"
    assert alive_wildcard("r1") == "swarm/r1/alive/robot/*"
    assert truth_wildcard("r1") == "swarm/r1/sim/truth/*"
    assert run_wildcard("r1") == "swarm/r1/**"


@pytest.mark.parametrize(
    "key",
    [
        "swarm/r1/robot/3",
        "swarm/r1/robot/03/cmd",
        "swarm/r1/robot/-3/cmd",
        "swarm/r1/robot/x/cmd",
        "swarm/r1/robot/9223372036854775808/cmd",
        "swarm/r1/robot/*/cmd",
        "swarm/r1/robot/3/fly",
        "swarm/r1/coord/teleport",
        "swarm/r1/sim/truth",
        "swarm/r1/alive/robot",
        "swarm/r 1/coord/plan",
        "swarm//coord/plan",
        "swarm/r1/**",
        "other/r1/coord/plan",
        "swarm/r1/coord/plan/",
        "",
    ],
)
def test_foreign_keys(key):
    with pytest.raises(KeyspaceError):
        parse_key(key)


def test_key_builders_refuse_bad_parts():
    for call in (
        lambda: robot_key("r1", 1, "fly"),
        lambda: robot_key("r1", -1, "cmd"),
        lambda: robot_key("r1", True, "cmd"),
        lambda: robot_key("r/1", 1, "cmd"),
        lambda: coord_key("r1", "cmd"),
        lambda: truth_key("r1", 1.0),
        lambda: robot_wildcard("r1", "plan"),
        lambda: run_wildcard("*"),
    ):
        with pytest.raises(KeyspaceError):
            call()


def test_message_keys_and_key_checked_decoding():
    leaves = {m.TYPE: parse_key(message_key(m)).leaf for m in samples()}
    assert leaves == {
        "MotionCommand": "cmd",
        "ObserveRequest": "observe",
        "Status": "status",
        "ObservationReport": "obs",
        "PlanMessage": "plan",
        "EstimateMessage": "estimate",
        "TruthMessage": "truth",
        "TruthSetMessage": "truths",
        "LinkRequest": "linkreq",
        "LinkReply": "linkrep",
        "LinkStats": "stats",
        "EmergencyStop": "estop",
        "EstopAck": "ack",
        "RobotEvent": "event",
        "ContactMessage": "contact",
    }
    assert message_key(SAMPLES["EstopAck"]) == estop_ack_key("r1") == "swarm/r1/estop/ack"
    assert message_key(SAMPLES["ContactMessage"]) == "swarm/r1/sim/contact"
    assert message_key(SAMPLES["RobotEvent"]) == "swarm/r1/coord/event"
    assert message_key(SAMPLES["LinkStats"]) == "swarm/r1/link/radio0/stats"
    assert message_key(SAMPLES["EmergencyStop"]) == "swarm/r1/estop"
    for msg in samples():
        assert type_for_key(message_key(msg)) is type(msg)
    data = encode(SAMPLES["Status"])
    assert decode(data, key="swarm/r1/robot/3/status") == SAMPLES["Status"]
    with pytest.raises(MessageError, match="belongs on 'swarm/r1/robot/3/status'") as info:
        decode(data, key="swarm/r1/robot/4/status")
    assert info.value.reason == "wrong-key"
    for key, expected, reason in [
        ("swarm/r2/robot/3/status", None, "wrong-key"),
        ("swarm/r1/robot/3/cmd", None, "unexpected-type"),
        ("swarm/r1/robot/3/cmd", Status, "wrong-key"),
        ("swarm/r1/alive/robot/3", None, "wrong-key"),
        ("elsewhere", None, "wrong-key"),
        ("elsewhere", Status, "wrong-key"),
    ]:
        with pytest.raises(MessageError) as info:
            decode(data, expected, key=key)
        assert info.value.reason == reason


# ---------------------------------------------------------------- schemas


def schema_errors(value, schema: dict, path: str = "") -> list[str]:
    """Minimal validator for the JSON-schema subset json_schema emits."""
    errs = []
    kind = schema.get("type")
    python = {"object": dict, "array": list, "string": str, "integer": int, "number": (int, float)}
    if "const" in schema and value != schema["const"]:
        errs.append(f"{path}: {value!r} != const")
    if kind and (not isinstance(value, python[kind]) or isinstance(value, bool)):
        return errs + [f"{path}: not {kind}"]
    if "enum" in schema and value not in schema["enum"]:
        errs.append(f"{path}: not in enum")
    if "pattern" in schema and not re.search(schema["pattern"], value):
        errs.append(f"{path}: pattern")
    for key, ok in (("minimum", lambda v, b: v >= b), ("maximum", lambda v, b: v <= b), ("maxLength", lambda v, b: len(v) <= b)):
        if key in schema and not ok(value, schema[key]):
            errs.append(f"{path}: {key}")
    if kind == "array":
        if len(value) > schema.get("maxItems", math.inf) or len(value) < schema.get("minItems", 0):
            errs.append(f"{path}: items")
        for i, v in enumerate(value):
            errs += schema_errors(v, schema["items"], f"{path}[{i}]")
    if kind == "object":
        errs += [f"{path}.{k}: missing" for k in schema["required"] if k not in value]
        for k, sub in schema["properties"].items():
            if k in value:
                errs += schema_errors(value[k], sub, f"{path}.{k}")
    return errs


@pytest.mark.parametrize("name", SAMPLES)
def test_json_schema_lists_exactly_the_encoded_fields(name):
    schema = json_schema(type(SAMPLES[name]))
    raw = raw_map(SAMPLES[name])
    assert list(schema["properties"]) == list(raw)
    optional = [f.name for f in fields(type(SAMPLES[name])) if f.metadata["wire"].optional]
    assert schema["required"] == [k for k in raw if k not in optional]
    assert schema["$schema"] == "https://json-schema.org/draft/2020-12/schema"
    assert schema["title"] == name and schema["properties"]["type"]["const"] == name
    assert schema_errors(raw, schema) == []
    json.dumps(schema)


def test_json_schema_catches_bad_values():
    raw = raw_map(SAMPLES["ObservationReport"])
    raw["ranges"][0] = -1.0
    raw["bearings"][0] = 4.0
    raw["robot"] = "3"
    errs = schema_errors(raw, json_schema(ObservationReport))
    assert errs == [".robot: not integer", ".ranges[0]: minimum", ".bearings[0]: maximum"]


# ---------------------------------------------------------------- drops, refusals, limits


def test_drop_counter_and_decode_or_drop(caplog):
    counter = DropCounter(log_every_s=0.0)  # every drop logged
    key = "swarm/r1/robot/3/obs"
    raw = raw_map(SAMPLES["ObservationReport"])
    raw["ranges"][0] = math.nan
    with caplog.at_level(logging.WARNING, logger="runtime.wire.messages"):
        assert decode_or_drop(b"\xc1", counter, key) is None
        assert decode_or_drop(msgpack.packb(raw), counter, key) is None
        assert decode_or_drop(msgpack.packb(raw), counter, key) is None
        assert decode_or_drop(encode(SAMPLES["Status"]), counter, key) is None
        assert decode_or_drop(encode(SAMPLES["ObservationReport"]), counter, key, known_ids={1, 3}) is None
        assert decode_or_drop(encode(SAMPLES["ObservationReport"]), counter, key) == SAMPLES["ObservationReport"]
    assert counter.snapshot() == {key: {"non-finite": 2, "undecodable": 1, "unexpected-type": 1, "unknown-id": 1}}
    assert counter.total == 5
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 5 and all("\n" not in line for line in lines)
    assert lines[1] == f"dropped message on {key} (non-finite): ObservationReport.ranges[0]: nan is not finite"


def test_a_flood_of_drops_is_counted_per_key_and_logged_at_a_bounded_rate(caplog):
    counter = DropCounter(log_every_s=3600.0)
    flood, other = "swarm/r1/robot/3/cmd", "swarm/r1/robot/4/cmd"
    with caplog.at_level(logging.WARNING, logger="runtime.wire.messages"):
        for _ in range(10_000):
            decode_or_drop(b"\xc1", counter, flood)
        decode_or_drop(b"\xc1", counter, other)
        counter.log_every_s = 0.0  # the interval is over
        decode_or_drop(b"\xc1", counter, flood)
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 3, lines  # the first of each key, then one line for the rest of the flood
    assert lines[2].startswith(f"dropped message on {flood} (undecodable)") and lines[2].endswith("(and 9999 more on this key since the last line)")
    assert counter.snapshot() == {flood: {"undecodable": 10_001}, other: {"undecodable": 1}}
    forged = DropCounter(log_every_s=60)
    for k in range(DropCounter.MAX_SOURCES + 500):  # every key a new one: the tables stay bounded
        forged.drop(f"swarm/r1/robot/{k}/cmd", MessageError("message", "bad", "undecodable"))
    assert len(forged.snapshot()) == DropCounter.MAX_SOURCES + 1 and forged.snapshot()["other keys"] == {"undecodable": 500}


@pytest.mark.parametrize("cls,size", [(MotionCommand, 64 * 2**10), (ObservationReport, 2**20), (EstimateMessage, 4 * 2**20)])
def test_each_type_has_a_size_limit_far_below_32_mib(cls, size):
    """A payload beyond its type's limit is refused before it is parsed (a 20 MB forgery on a command key costs nothing)."""
    assert cls.MAX_BYTES == size
    key = message_key(SAMPLES[cls.__name__])
    payload = encode(SAMPLES[cls.__name__])
    assert decode(payload, key=key) == SAMPLES[cls.__name__]
    with pytest.raises(MessageError, match=rf"{size + 1} bytes, at most {size} allowed") as info:
        decode(payload + bytes(size + 1 - len(payload)), key=key)
    assert info.value.reason == "size"
    with pytest.raises(MessageError, match=r"at most 65536 allowed for MotionCommand"):  # unknown key: the type's limit still applies
        decode(msgpack.packb({**raw_map(SAMPLES["MotionCommand"]), "pad": ["x" * 100] * 1000}))


def test_rate_limit():
    limit = RateLimit(per_s=10.0, burst=5)
    assert sum(limit.allow() for _ in range(1000)) == 5 and limit.suppressed == 995
    time.sleep(0.35)
    assert 3 <= sum(limit.allow() for _ in range(100)) <= 5


def test_undecodable_command_is_refused_when_its_header_is_readable():
    raw = raw_map(SAMPLES["MotionCommand"])
    raw["turn_rad"] = math.nan
    with pytest.raises(MessageError) as info:
        decode(msgpack.packb(raw), MotionCommand, key="swarm/r1/robot/3/cmd")
    status = refusal_status(info.value, stamp_ns=5)
    assert status == Status(run="r1", step=7, stamp_ns=5, robot=3, state="refused", reason=str(info.value), cmd_id=2**62 + 5)
    assert "MotionCommand.turn_rad: nan is not finite" in status.reason
    with pytest.raises(MessageError) as info:
        decode(msgpack.packb({**raw, "robot": 4}), key="swarm/r1/robot/3/cmd")
    assert info.value.header == {"type": "MotionCommand"} and refusal_status(info.value) is None
    del raw["robot"]
    with pytest.raises(MessageError) as info:
        decode(msgpack.packb(raw))
    assert info.value.header == {"type": "MotionCommand", "run": "r1", "step": 7, "cmd_id": 2**62 + 5}
    assert refusal_status(info.value) is None
    with pytest.raises(MessageError) as info:
        decode(b"\xc1")
    assert refusal_status(info.value) is None


def test_command_of_an_unsupported_version_gets_a_refusal_naming_the_version():
    raw = {**raw_map(SAMPLES["MotionCommand"]), "v": 2}
    with pytest.raises(MessageError) as info:
        decode(msgpack.packb(raw), MotionCommand, key="swarm/r1/robot/3/cmd")
    assert info.value.reason == "version"
    status = refusal_status(info.value, stamp_ns=5)
    assert status is not None and (status.step, status.robot, status.cmd_id) == (7, 3, 2**62 + 5)
    assert status.reason == "MotionCommand.v: version 2 is not supported (this decoder reads version 1)"
    with pytest.raises(MessageError) as info:  # on another robot's key: nobody answers for it
        decode(msgpack.packb(raw), MotionCommand, key="swarm/r1/robot/4/cmd")
    assert refusal_status(info.value) is None


def test_targeted_emergency_stop():
    everyone = EmergencyStop(run="r1", step=0, source="s", reason="r")
    one = EmergencyStop(run="r1", step=0, source="s", reason="r", robots=[4])
    assert everyone.applies_to(3) and everyone.applies_to(4)
    assert one.applies_to(4) and not one.applies_to(3)


def test_command_limits():
    limits = CommandLimits(max_drive_m=0.5)

    def cmd(turn, drive):
        return MotionCommand(run="r", step=1, robot=1, config=1, turn_rad=turn, drive_m=drive)

    assert limits.refusal(cmd(math.pi, 0.5)) is None and limits.refusal(cmd(-math.pi, 0.0)) is None
    assert "turn_rad 3.2 exceeds" in limits.refusal(cmd(3.2, 0.1))
    assert "drive_m -0.1 is negative" in limits.refusal(cmd(0.0, -0.1))
    assert "drive_m 0.6 exceeds the limit 0.5 m" in limits.refusal(cmd(0.0, 0.6))
    for bad in ({"max_drive_m": 0}, {"max_drive_m": math.inf}, {"max_turn_rad": -1}):
        with pytest.raises(SwarmInputError):
            CommandLimits(**bad)


# ---------------------------------------------------------------- docs/protocol.md


def _bound(x: float) -> str:
    return {math.pi: "pi", -math.pi: "-pi"}.get(x, f"{x:g}")


def field_table(cls: type[Message], header: bool = False) -> str:
    """Markdown table of the fields (header fields only, or only the type's own) for docs/protocol.md."""
    rows = ["| field | type | unit | valid values | meaning |", "| --- | --- | --- | --- | --- |"]
    if header:
        rows += [
            "| `type` | str |  | a type name below | message type |",
            "| `v` | int |  | 1 | major schema version of the type |",
        ]
    for f in fields(cls):
        if (f.name in ("run", "step", "stamp_ns")) != header:
            continue
        w = f.metadata["wire"]
        dims = "".join(f"[{d if d is not None else ''}]" for d in w.shape)
        kind = {"id": "robot id", "int": "int", "float": "float", "str": "str"}[w.kind] + dims
        if w.kind == "float":
            valid = "finite"
            if w.minimum is not None and w.maximum is not None:
                valid += f", in [{_bound(w.minimum)}, {_bound(w.maximum)}]" + (f" ± {w.slack:g}" if w.slack else "")
            elif w.minimum is not None:
                valid += f", >= {_bound(w.minimum)}"
        elif w.kind == "str":
            valid = ", ".join(w.choices) if w.choices else (f"`{w.pattern}`" if w.pattern else f"<= {w.max_length} chars")
        else:
            valid = ">= 0"
        rows.append(f"| `{f.name}` | {kind} | {w.unit} | {valid} | {w.doc} |")
    return "\n".join(rows)


def test_protocol_doc_tables_match_the_code():
    doc = PROTOCOL_MD.read_text()
    for table in [field_table(Message, header=True)] + [field_table(cls) for cls in MESSAGE_TYPES]:
        assert table in doc, f"docs/protocol.md is out of date; expected this table:\n{table}"


def test_protocol_doc_examples_decode_to_their_json():
    doc = PROTOCOL_MD.read_text()
    hexes = re.findall(r"```text\n([0-9a-f\n]+)```", doc)
    jsons = re.findall(r"```json\n(.*?)```", doc, re.S)
    assert len(hexes) == len(jsons) == 2
    for hex_text, json_text in zip(hexes, jsons, strict=True):
        msg = decode(bytes.fromhex(hex_text.replace("\n", "")))
        assert raw_map(msg) == json.loads(json_text)
