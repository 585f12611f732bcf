"""The frame codec (runtime/gateway/frames.py) against docs/gateway-protocol.md: layout, CRC, bodies, resynchronisation."""

from __future__ import annotations

import random
import re
import struct
from pathlib import Path

import pytest
from hypothesis import given, settings, strategies as st

from runtime.gateway.frames import (
    BODIES,
    BROADCAST,
    MAX_ENTRIES,
    MAX_PAYLOAD,
    MAX_TEXT,
    EmptyBody,
    ErrorBody,
    Frame,
    FrameDecoder,
    FrameError,
    FrameType,
    HeartbeatBody,
    MotionBody,
    ObservationBody,
    RefusalBody,
    RefusalCode,
    RunBody,
    StepBody,
    crc16,
    encode_frame,
)

DOC = Path(__file__).resolve().parents[2] / "docs" / "gateway-protocol.md"

u8 = st.integers(0, 0xFF)
u16 = st.integers(0, 0xFFFF)
u32 = st.integers(0, 0xFFFFFFFF)
f32 = st.floats(width=32, allow_nan=False, allow_infinity=False)


def _short_text(max_bytes: int = MAX_TEXT) -> st.SearchStrategy[str]:
    """UTF-8 text of at most ``max_bytes`` bytes (the codec keeps at most MAX_TEXT bytes)."""
    return st.text(max_size=max_bytes).filter(lambda s: len(s.encode("utf-8")) <= max_bytes)


def _observation() -> st.SearchStrategy[ObservationBody]:
    @st.composite
    def build(draw) -> ObservationBody:
        parts = draw(st.integers(1, 255))
        part = draw(st.integers(0, parts - 1))
        entries = draw(st.lists(st.tuples(u16, f32, f32), max_size=MAX_ENTRIES))
        return ObservationBody(draw(u32), draw(u32), part, parts, tuple(entries))

    return build()


BODY_STRATEGIES = {
    EmptyBody: st.just(EmptyBody()),
    StepBody: st.builds(StepBody, u32),
    MotionBody: st.builds(MotionBody, u32, f32, f32),
    HeartbeatBody: st.builds(HeartbeatBody, u32),
    RefusalBody: st.builds(RefusalBody, u32, u8, _short_text()),
    ErrorBody: st.builds(ErrorBody, u8, _short_text()),
    ObservationBody: _observation(),
    RunBody: st.builds(RunBody, u32),
}


@st.composite
def frames(draw) -> tuple[Frame, object]:
    kind = draw(st.sampled_from(list(FrameType)))
    body = draw(BODY_STRATEGIES[BODIES[kind]])
    return Frame.of(draw(u16), draw(u16), kind, body), body


@given(frames())
@settings(max_examples=300)
def test_every_frame_type_and_body_round_trips(item):
    frame, body = item
    wire = encode_frame(frame)
    assert wire[0] == 0xA5 and wire[1] == len(frame.payload) <= MAX_PAYLOAD
    assert len(wire) == 9 + len(frame.payload)
    decoder = FrameDecoder()
    assert decoder.feed(wire) == [frame]
    assert frame.body() == body  # float32 values come back exactly
    assert decoder.pending == 0 and decoder.stats.frames == 1


@given(st.lists(frames(), min_size=1, max_size=5), st.lists(st.integers(1, 40), max_size=10))
def test_frames_survive_any_chunking(items, cuts):
    wire = b"".join(encode_frame(f) for f, _ in items)
    decoder, found, at = FrameDecoder(), [], 0
    for cut in cuts:
        found += decoder.feed(wire[at:at + cut])
        at += cut
    found += decoder.feed(wire[at:])
    assert found == [f for f, _ in items]


def test_crc_check_value():
    assert crc16(b"123456789") == 0x29B1


def test_bad_crc_is_rejected_and_counted():
    good = encode_frame(Frame.of(3, 7, FrameType.ACCEPTED, StepBody(12)))
    bad = good[:-1] + bytes([good[-1] ^ 0x01])
    decoder = FrameDecoder()
    assert decoder.feed(bad) == []
    assert decoder.stats.crc_errors == 1
    assert decoder.feed(good) == [Frame(3, 7, FrameType.ACCEPTED, struct.pack("<I", 12))]


def test_length_above_250_is_a_false_start():
    good = encode_frame(Frame.of(1, 2, FrameType.HEARTBEAT, HeartbeatBody(5)))
    decoder = FrameDecoder()
    assert decoder.feed(bytes([0xA5, 251, 0xA5, 0xFF]) + good) == [Frame.of(1, 2, FrameType.HEARTBEAT, HeartbeatBody(5))]
    assert decoder.stats.length_errors == 2
    with pytest.raises(FrameError, match="at most 250"):
        encode_frame(Frame(1, 2, FrameType.ERROR, bytes(251)))


def test_truncated_frame_is_held_then_completed():
    frame = Frame.of(4, 9, FrameType.OBSERVATION, ObservationBody(12, 1000, 0, 1, ((5, 0.25, 1.5),)))
    wire = encode_frame(frame)
    decoder = FrameDecoder()
    for k in range(len(wire) - 1):
        assert decoder.feed(wire[k:k + 1]) == []
        assert decoder.pending == k + 1
    assert decoder.feed(wire[-1:]) == [frame]
    assert decoder.pending == 0


noise = st.binary(max_size=60) | st.lists(st.sampled_from([0xA5, 0x00, 0xFF, 0x04, 0xFA, 0x0C]), max_size=30).map(bytes)


@given(noise, st.lists(frames(), min_size=1, max_size=4), st.lists(noise, min_size=4, max_size=4), noise)
@settings(derandomize=True, max_examples=300)  # derandomized: a 1-in-65536 CRC match of noise never flakes a run
def test_noise_around_frames_loses_no_frame(lead, items, gaps, tail):
    wire = lead + b"".join(encode_frame(f) + gap for (f, _), gap in zip(items, gaps, strict=False)) + tail
    decoder = FrameDecoder()
    found = decoder.feed(wire)
    while decoder.pending:  # the line goes quiet: the reader gives up on the START it waits on
        found += decoder.resync()
    assert found == [f for f, _ in items]


def test_resync_after_corrupted_length():
    first = bytearray(encode_frame(Frame.of(1, 1, FrameType.DONE, StepBody(3))))
    second = Frame.of(1, 2, FrameType.ACCEPTED, StepBody(4))
    first[1] = 200  # the corrupted LEN promises 209 bytes that never come
    decoder = FrameDecoder()
    assert decoder.feed(bytes(first) + encode_frame(second)) == []
    assert decoder.pending == len(first) + 13
    assert decoder.resync() == [second]
    assert decoder.pending == 0
    assert decoder.stats.length_errors == 1
    assert decoder.resync() == []  # nothing pending: nothing to give up


def test_receive_gives_up_on_a_partial_frame_only_after_a_quiet_line():
    from runtime.gateway.frames import QUIET_S

    first = bytearray(encode_frame(Frame.of(1, 1, FrameType.DONE, StepBody(3))))
    second = Frame.of(1, 2, FrameType.ACCEPTED, StepBody(4))
    first[1] = 200
    decoder = FrameDecoder()
    assert decoder.receive(bytes(first) + encode_frame(second), now=10.0) == []
    assert decoder.receive(b"", now=10.0 + QUIET_S / 2) == []  # not quiet long enough: still waiting
    assert decoder.receive(b"", now=10.0 + 2 * QUIET_S) == [second]
    assert decoder.pending == 0


def test_body_size_errors_name_the_body_and_sizes():
    with pytest.raises(FrameError, match=r"StepBody: payload of 3 bytes, expected 4"):
        StepBody.unpack(b"\x00\x00\x00")
    with pytest.raises(FrameError, match=r"MotionBody: payload of 13 bytes, expected 12"):
        Frame(0, 1, FrameType.COMMAND, bytes(13)).body()
    with pytest.raises(FrameError, match=r"EmptyBody: payload of 1 bytes, expected 0"):
        Frame(0, 1, FrameType.ESTOP, b"\x00").body()
    with pytest.raises(FrameError, match=r"RefusalBody: payload of 2 bytes, expected 5"):
        RefusalBody.unpack(b"\x00\x00")
    with pytest.raises(FrameError, match=r"RefusalBody: text is not UTF-8"):
        RefusalBody.unpack(bytes(5) + b"\xff")
    with pytest.raises(FrameError, match=r"ObservationBody: 15 bytes is not 10 \+ k \* 10"):
        ObservationBody.unpack(bytes(15))
    with pytest.raises(FrameError, match=r"part 1 is not in \[0, parts=1\)"):
        ObservationBody.unpack(struct.pack("<IIBB", 1, 0, 1, 1))
    with pytest.raises(FrameError, match=r"25 entries, at most 24"):
        ObservationBody(1, 0, 0, 1, ((1, 0.0, 0.0),) * (MAX_ENTRIES + 1)).pack()
    with pytest.raises(FrameError, match=r"StepBody: .*\(values \(-1,\)\)"):
        StepBody(-1).pack()
    with pytest.raises(FrameError, match=r"unknown frame type 0x42"):
        Frame(0, 1, 0x42, b"").body()
    with pytest.raises(FrameError, match=r"COMMAND carries a MotionBody, not a StepBody"):
        Frame.of(0, 1, FrameType.COMMAND, StepBody(1))
    with pytest.raises(FrameError, match=r"robot id 65536"):
        encode_frame(Frame(0x10000, 1, FrameType.ESTOP, b""))


# -- the example frames of docs/gateway-protocol.md ---------------------------------------------

_HEAD = re.compile(r"^(?P<name>[A-Z_]+) (?:robot (?P<robot>\d+)|to every robot \(0xFFFF\)), seq (?P<seq>\d+)(?:: (?P<rest>.*))?$")
_NUM = r"(-?[0-9.]+)"


def _doc_examples() -> list[tuple[str, bytes]]:
    """(description, bytes) of every row of the "Example frames" table."""
    text = DOC.read_text()
    section = text.split("## Example frames", 1)[1].split("\n## ", 1)[0]
    rows = []
    for line in section.splitlines():
        m = re.fullmatch(r"\|\s*(.+?)\s*\|\s*`([0-9a-f ]+)`\s*\|", line.strip())
        if m:
            rows.append((m.group(1), bytes.fromhex(m.group(2))))
    return rows


def _expected(description: str) -> Frame:
    """The frame a row's description says, built with the codec from the described fields."""
    head = _HEAD.match(description)
    assert head, f"cannot parse the description {description!r}"
    kind = FrameType[head["name"]]
    robot = BROADCAST if head["robot"] is None else int(head["robot"])
    rest = head["rest"] or ""

    def field(pattern: str, cast=int):
        m = re.search(pattern, rest)
        assert m, f"{description!r}: no {pattern!r}"
        return cast(m.group(1))

    cls = BODIES[kind]
    if cls is EmptyBody:
        body = EmptyBody()
    elif cls is StepBody:
        body = StepBody(field(r"step (\d+)"))
    elif cls is MotionBody:
        body = MotionBody(field(r"step (\d+)"), field(rf"turn {_NUM} rad", float), field(rf"drive {_NUM} m", float))
    elif cls is HeartbeatBody:
        body = HeartbeatBody(field(r"time (\d+) ms"))
    elif cls is RunBody:
        body = RunBody(field(r"epoch (\d+)"))
    elif cls is RefusalBody:
        code = re.search(r"code (\d+) \(([A-Z_]+)\)", rest)
        assert int(code.group(1)) == RefusalCode[code.group(2)]
        body = RefusalBody(field(r"step (\d+)"), int(code.group(1)), field(r'"([^"]*)"', str))
    elif cls is ObservationBody:
        part = re.search(r"part (\d+) of (\d+)", rest)
        entries = tuple((int(i), float(r), float(b)) for i, r, b in re.findall(rf"robot (\d+) at {_NUM} m / {_NUM} rad", rest))
        body = ObservationBody(field(r"step (\d+)"), field(r"stamp (\d+) ms"), int(part.group(1)), int(part.group(2)), entries)
    else:
        raise AssertionError(f"no description parser for {cls.__name__}")
    return Frame.of(robot, int(head["seq"]), kind, body)


def test_doc_example_frames_decode_to_their_descriptions_and_reencode():
    examples = _doc_examples()
    assert len(examples) >= 9, "the example table of docs/gateway-protocol.md was not found"
    assert {FrameType[d.split()[0]] for d, _ in examples} >= {FrameType.COMMAND, FrameType.OBSERVATION, FrameType.REFUSED, FrameType.ESTOP,
                                                               FrameType.RUN, FrameType.RUN_ACK}
    for description, wire in examples:
        expected = _expected(description)
        decoded = FrameDecoder().feed(wire)
        assert decoded == [expected], description
        assert encode_frame(decoded[0]) == wire, description
        assert encode_frame(expected) == wire, description


def test_decoder_statistics_count_skipped_bytes():
    decoder = FrameDecoder()
    rng = random.Random(1)
    junk = bytes(rng.choice([0x00, 0x11, 0x7F]) for _ in range(17))  # no START byte
    frame = Frame.of(2, 3, FrameType.RESET, EmptyBody())
    assert decoder.feed(junk + encode_frame(frame)) == [frame]
    assert decoder.stats.skipped_bytes == 17


def test_long_text_is_cut_on_a_character_boundary():
    from runtime.gateway.frames import MAX_TEXT, ErrorBody, RefusalBody

    refusal = RefusalBody(1, 1, "a" + "é" * 150)
    back = RefusalBody.unpack(refusal.pack())
    assert len(back.reason.encode()) <= MAX_TEXT and refusal.reason.startswith(back.reason)
    error = ErrorBody(1, "€" * 100)
    assert ErrorBody.unpack(error.pack()).text == "€" * (MAX_TEXT // 3)


@pytest.mark.parametrize("body", [
    StepBody(2**32 + 5), MotionBody(2**32, 0.0, 0.0), MotionBody(1, 1e39, 0.0), MotionBody(1, 0.0, -1e39), RunBody(-1),
])
def test_values_beyond_the_wire_types_are_frame_errors_not_crashes(body):
    with pytest.raises(FrameError, match=type(body).__name__):
        body.pack()


def test_fits_f32_is_the_float32_range():
    from runtime.gateway.frames import F32_MAX, fits_f32

    assert fits_f32(F32_MAX) and fits_f32(-F32_MAX) and fits_f32(0.0)
    assert not any(fits_f32(v) for v in (1e39, -1e39, float("nan"), float("inf")))
    assert struct.unpack("<f", struct.pack("<f", F32_MAX))[0] == F32_MAX
