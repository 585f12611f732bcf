"""Frames of one batch of work go out in one write; other threads' and unbatched writes at once."""

from __future__ import annotations

import threading

import pytest

from robot_agent.write_batch import WriteBatch
from runtime.gateway.frames import Frame, FrameDecoder, FrameType, MotionBody, StepBody, encode_frame


def test_writes_outside_a_batch_go_out_at_once():
    wire: list[bytes] = []
    batch = WriteBatch(wire.append)
    batch.write(b"a")
    batch.write(b"b")
    assert wire == [b"a", b"b"]


def test_a_batch_is_one_write_in_order_and_decodes_to_the_same_frames():
    wire: list[bytes] = []
    batch = WriteBatch(wire.append)
    frames = [Frame.of(3, 7, FrameType.ACCEPTED, StepBody(12)), Frame.of(3, 7, FrameType.DONE, StepBody(12)),
              Frame.of(4, 8, FrameType.COMMAND, MotionBody(12, -3.14159, 0.25))]
    with batch.collect():
        for f in frames:
            batch.write(encode_frame(f))
        assert wire == []  # nothing on the wire before the batch ends
    assert len(wire) == 1
    decoded = FrameDecoder().feed(wire[0])
    assert [(f.robot, f.seq, f.type, f.body()) for f in decoded] == [(f.robot, f.seq, f.type, f.body()) for f in frames]


def test_an_empty_batch_writes_nothing_and_a_nested_one_writes_with_the_outer():
    wire: list[bytes] = []
    batch = WriteBatch(wire.append)
    with batch.collect():
        pass
    assert wire == []
    with batch.collect():
        batch.write(b"a")
        with batch.collect():
            batch.write(b"b")
        assert wire == []
        batch.write(b"c")
    assert wire == [b"abc"]


def test_another_threads_writes_are_not_held_by_a_batch():
    wire: list[bytes] = []
    batch = WriteBatch(wire.append)
    with batch.collect():
        batch.write(b"mine")
        other = threading.Thread(target=batch.write, args=(b"theirs",))
        other.start()
        other.join()
        assert wire == [b"theirs"]
    assert wire == [b"theirs", b"mine"]


def test_what_a_failing_batch_wrote_still_goes_out():
    wire: list[bytes] = []
    batch = WriteBatch(wire.append)
    with pytest.raises(RuntimeError), batch.collect():
        batch.write(b"sent before the failure")
        raise RuntimeError("handler failed")
    assert wire == [b"sent before the failure"]
    batch.write(b"next")  # the thread is out of the batch
    assert wire[-1] == b"next"
