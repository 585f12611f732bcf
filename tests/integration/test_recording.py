"""MCAP recording (runtime.recording.mcap_log): round trip, thread-safe writes, corrupt files, a live Zenoh run.

Every file is a real MCAP in tmp_path, read back with mcap's own readers (not the writer). With real processes:
tests/system/test_recording_processes.py."""

from __future__ import annotations

import json
import random
import threading
import time
import uuid
from pathlib import Path

import pytest
from mcap.reader import make_reader
from mcap.records import Channel, Message
from mcap.stream_reader import StreamReader

from runtime.errors import SwarmInputError
from runtime.recording.mcap_log import McapRecorder, read_messages, record_run, recording_info, recover
from runtime.wire.keys import coord_key, robot_key
from runtime.wire.messages import (
    MESSAGE_TYPES,
    EstimateMessage,
    MotionCommand,
    ObservationReport,
    PlanMessage,
    Status,
    TruthMessage,
    encode,
    json_schema,
    message_key,
)

RUN = "rec1"


def sample_messages() -> list[tuple[str, bytes]]:
    """Encoded messages of six types, plus raw bytes on an unknown key and a bad payload on a typed key."""
    msgs = []
    for step in range(1, 4):
        for robot in (0, 1, 2):
            msgs.append(MotionCommand(run=RUN, step=step, robot=robot, config=1, turn_rad=0.1 * robot, drive_m=0.05))
            msgs.append(Status(run=RUN, step=step, robot=robot, state="done", reason=""))
            msgs.append(ObservationReport(run=RUN, step=step, robot=robot, observed=[(robot + 1) % 3], ranges=[0.3], bearings=[0.5]))
            msgs.append(TruthMessage(run=RUN, step=step, robot=robot, pose=[0.1 * step, 0.2, 0.0]))
        msgs.append(PlanMessage(run=RUN, step=step, config=1, n_anchors=2, groups=[[step % 3]]))
        msgs.append(EstimateMessage(run=RUN, step=step, ids=[0, 1, 2], poses=[[0, 0, 0], [1, 0, 0], [0, 1, 0]],
                                    cov=[[[1e-4, 0, 0], [0, 1e-4, 0], [0, 0, 1e-3]]] * 3))
    out = [(message_key(m), encode(m)) for m in msgs]
    out.insert(5, (f"swarm/{RUN}/debug/raw", b"\x00\xffnot msgpack"))
    out.append((robot_key(RUN, 0, "status"), b"\xc1garbage"))  # typed key, undecodable
    return out


def write_sample(path: Path, foxglove: bool = True) -> list[tuple[str, bytes, int]]:
    written = []
    meta = {"seed": 7, "parameters": {"w_v": 0.5}, "trajectory": {"ids": [0, 1, 2]}}
    with McapRecorder(path, RUN, meta, foxglove=foxglove) as rec:
        for i, (key, payload) in enumerate(sample_messages()):
            log_time = 1_700_000_000_000_000_000 + i * 1_000_000
            rec.write(key, payload, log_time_ns=log_time)
            written.append((key, payload, log_time))
    return written


def test_round_trip_seeking_and_stream_reader(tmp_path):
    path = tmp_path / "run.mcap"
    written = write_sample(path, foxglove=False)  # the raw layout only; derived channels: tests/integration/test_foxglove.py
    expected = [(k, p, t) for k, p, t in written]

    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics.message_count == len(written)
        got = [(ch.topic, msg.data, msg.log_time) for _schema, ch, msg in reader.iter_messages(log_time_order=True)]
        assert got == expected
        schemas = {s.name: s for s in summary.schemas.values()}
        assert set(schemas) == {"MotionCommand", "Status", "ObservationReport", "TruthMessage", "PlanMessage", "EstimateMessage"}
        for name, schema in schemas.items():
            assert schema.encoding == "jsonschema"
            cls = next(m for m in MESSAGE_TYPES if m.TYPE == name)
            assert schema.data == json.dumps(json_schema(cls)).encode()
        channels = {c.topic: c for c in summary.channels.values()}
        assert channels[f"swarm/{RUN}/debug/raw"].schema_id == 0
        assert all(c.message_encoding == "msgpack" for c in channels.values())
        # one schema per type, shared by its channels
        assert channels[robot_key(RUN, 0, "cmd")].schema_id == channels[robot_key(RUN, 2, "cmd")].schema_id
        (run_meta,) = [m for m in reader.iter_metadata() if m.name == "run"]
        assert run_meta.metadata["run"] == RUN and json.loads(run_meta.metadata["seed"]) == 7
        assert json.loads(run_meta.metadata["parameters"]) == {"w_v": 0.5}
        assert {"python", "numpy", "zenoh", "mcap", "inchworm-swarm"} <= set(json.loads(run_meta.metadata["versions"]))

    stream_channels: dict[int, Channel] = {}
    got = []
    for record in StreamReader(str(path), validate_crcs=True).records:
        if isinstance(record, Channel):
            stream_channels[record.id] = record
        elif isinstance(record, Message):
            got.append((stream_channels[record.channel_id].topic, record.data, record.log_time))
    assert got == expected

    assert [(k, p, t) for k, p, t, _pub in read_messages(path)] == expected
    # publish time: the message's stamp_ns where it decodes, else the log time
    pubs = {(k, t): pub for k, _p, t, pub in read_messages(path)}
    k0, p0, t0 = written[0]
    assert pubs[(k0, t0)] != t0 and abs(pubs[(k0, t0)] - time.time_ns()) < 60e9
    assert pubs[(f"swarm/{RUN}/debug/raw", written[5][2])] == written[5][2]

    info = recording_info(path)
    assert info["complete"] and info["indexed"] and info["messages"] == len(written)
    assert info["undecodable"] == 1
    bad = [c for c in info["channels"] if c["undecodable"]]
    assert [c["topic"] for c in bad] == [robot_key(RUN, 0, "status")] and bad[0]["reasons"] == {"undecodable": 1}
    assert info["metadata"]["run"]["seed"] == 7 and info["metadata"]["recorder"]["clean_stop"] is True
    assert info["duration_s"] == pytest.approx((len(written) - 1) * 1e-3)


def test_thread_safe_writes(tmp_path):
    path = tmp_path / "threads.mcap"
    with McapRecorder(path, RUN, {}) as rec:
        def burst(robot: int) -> None:
            for step in range(300):
                m = Status(run=RUN, step=step, robot=robot, state="accepted", reason="")
                rec.write(message_key(m), encode(m))
        threads = [threading.Thread(target=burst, args=(r,)) for r in range(4)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    counts = {c["topic"]: c["messages"] for c in recording_info(path)["channels"]}
    assert counts == {robot_key(RUN, r, "status"): 300 for r in range(4)}


def _complete_file(tmp_path: Path) -> Path:
    path = tmp_path / "good.mcap"
    rng = random.Random(0)
    with McapRecorder(path, RUN, {"seed": 0}, chunk_bytes=4096) as rec:
        for step in range(1500):
            m = ObservationReport(run=RUN, step=step, robot=step % 5, observed=[9], ranges=[rng.random()], bearings=[0.1])
            rec.write(message_key(m), encode(m))
    return path


def _check_rejected(path: Path, out: Path, words: str) -> None:
    for call in (lambda: recording_info(path), lambda: list(read_messages(path)), lambda: recover(path, out)):
        with pytest.raises(SwarmInputError) as err:
            call()
        assert str(path) in str(err.value) and words in str(err.value), str(err.value)
    assert not out.exists()


def test_corrupt_files_raise_input_errors(tmp_path):
    rng = random.Random(1)
    out = tmp_path / "out.mcap"
    noise = tmp_path / "noise.mcap"
    noise.write_bytes(bytes(rng.randrange(256) for _ in range(5000)))
    _check_rejected(noise, out, "not an MCAP file")
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    _check_rejected(empty, out, "not an MCAP file")

    good = _complete_file(tmp_path)
    data = good.read_bytes()
    header_cut = tmp_path / "header.mcap"
    header_cut.write_bytes(data[:14])
    _check_rejected(header_cut, out, "truncated header")

    for where in (0.3, 0.5, 0.7):
        damaged = tmp_path / f"damaged{where}.mcap"
        at = int(len(data) * where)
        damaged.write_bytes(data[:at] + bytes(rng.randrange(256) for _ in range(300)) + data[at + 300:])
        _check_rejected(damaged, out, "corrupt")

    missing = tmp_path / "missing.mcap"
    _check_rejected(missing, out, "no such file")


def test_record_run_over_zenoh(tmp_path):
    from runtime.wire.transport import open_loopback_hub, publish

    run = f"z{uuid.uuid4().hex[:8]}"
    hub_session, member, _ = open_loopback_hub()
    path = tmp_path / "live.mcap"
    stop, ready = threading.Event(), threading.Event()
    recorder = {}
    with hub_session as session:
        result = {}
        thread = threading.Thread(target=lambda: result.update(record_run(
            member, run, path, {"seed": 5}, stop, on_ready=lambda rec: (recorder.setdefault("rec", rec), ready.set()))))
        thread.start()
        try:
            assert ready.wait(20)
            deadline = time.monotonic() + 10
            while recorder["rec"].count == 0:  # until the subscription has reached the hub
                publish(session, f"swarm/{run}/probe", b"probe")
                time.sleep(0.05)
                assert time.monotonic() < deadline
            sent = []
            for step in range(20):
                m = MotionCommand(run=run, step=step, robot=step % 2, config=1, turn_rad=0.0, drive_m=0.1)
                sent.append((message_key(m), encode(m)))
                publish(session, *sent[-1])
            est = EstimateMessage(run=run, step=20, ids=[0, 1], poses=[[0, 0, 0], [1, 0, 0]], cov=[[[1, 0, 0], [0, 1, 0], [0, 0, 1]]] * 2)
            sent.append((coord_key(run, "estimate"), encode(est)))
            publish(session, *sent[-1])
            publish(session, "swarm/other-run/coord/plan", b"not ours")
            deadline = time.monotonic() + 10
            while recorder["rec"].count < len(sent) + 1 and time.monotonic() < deadline:
                time.sleep(0.02)
        finally:
            stop.set()
            thread.join(20)
    got = [(k, p) for k, p, _t, _pub in read_messages(path) if not k.endswith("/probe")]
    assert got == sent
    assert result["messages"] >= len(sent) + 1 and result["undecodable"] == 0
    assert recording_info(path)["metadata"]["run"]["seed"] == 5


def test_a_stopped_recording_keeps_what_arrives_until_it_is_quiet_and_no_longer_than_its_limit(tmp_path):
    """``drain`` after a stop (``swarm record``'s SIGINT): a message arriving 0.25 s after another, within the 0.5 s
    quiet time, is kept and the drain ends once quiet; a run that goes on publishing holds it at most
    ``DRAIN_LIMIT`` times the quiet time."""
    from runtime.recording.mcap_log import DRAIN_LIMIT, drain

    status = Status(run=RUN, step=0, robot=1, state="done", reason="")
    with McapRecorder(tmp_path / "late.mcap", RUN, {}) as rec:
        late = [threading.Timer(delay, rec.write, (message_key(status), encode(status))) for delay in (0.05, 0.3)]
        for timer in late:
            timer.start()
        drain(rec, 0.5)
        assert rec.count == 2
        for timer in late:
            timer.join()

    with McapRecorder(tmp_path / "busy.mcap", RUN, {}) as rec:
        busy = threading.Event()

        def publish() -> None:
            while not busy.wait(0.01):
                rec.write(message_key(status), encode(status))

        writer = threading.Thread(target=publish)
        writer.start()
        start = time.monotonic()
        drain(rec, 0.05)
        held = time.monotonic() - start
        busy.set()
        writer.join()
    assert DRAIN_LIMIT * 0.05 <= held < DRAIN_LIMIT * 0.05 + 1.0
