"""Foxglove views: derived SceneUpdate scenes (runtime.recording.foxglove_scene), their MCAP channels, the live view's
websocket server in-process (beside a real launch: tests/system/test_foxglove_runs.py)."""

from __future__ import annotations

import base64
import json
import os
import socket
import sys

import pytest
from mcap.reader import make_reader

from runtime.errors import SwarmInputError
from runtime.recording.foxglove_scene import (
    SCENE_UPDATE_SCHEMA,
    TOPIC_DESIRED,
    TOPIC_ESTIMATED,
    TOPIC_TRUE,
    SceneDeriver,
    estimated_scene,
    schema_errors,
    trajectory_configurations,
)
from runtime.recording.mcap_log import McapRecorder, is_derived, read_messages, recording_info, recover
from runtime.wire.messages import EstimateMessage, PlanMessage, RobotEvent, TruthMessage, TruthSetMessage, encode, message_key
from tests.integration.test_recording import RUN, sample_messages

TRAJ = {"robots": [0, 1, 2], "initial_poses": [[0, 0, 0], [0.2, 0, 0], [0, 0.2, 0]],
        "configurations": [[[0.3, 0.0], [0.5, 0.0], [0.3, 0.2]], [[0.6, 0.1], [0.8, 0.1], [0.6, 0.3]]]}
COV = [[[1e-4, 0, 0], [0, 1e-4, 0], [0, 0, 1e-3]]] * 3


def run_messages() -> list:
    """Step 0 estimate, a plan for configuration 2 (groups [0], [1, 2] at steps 1, 2), truths and estimates."""
    msgs = [EstimateMessage(run=RUN, step=0, ids=[0, 1, 2], poses=[[0, 0, 0], [0.2, 0, 0], [0, 0.2, 0]], cov=COV),
            PlanMessage(run=RUN, step=1, config=2, n_anchors=2, groups=[[0], [1, 2]])]
    for step in (1, 2):
        msgs += [TruthMessage(run=RUN, step=step, robot=r, pose=[0.1 * step + r, 0.0, 0.0]) for r in range(3)]
        msgs.append(TruthSetMessage(run=RUN, step=step, ids=[0, 1, 2], poses=[[0.1 * step + r, 0.0, 0.0] for r in range(3)]))
        msgs.append(EstimateMessage(run=RUN, step=step, ids=[0, 1, 2], poses=[[0.1 * step + r, 0.01, 0.0] for r in range(3)], cov=COV))
    return msgs


def test_scenes_follow_the_schema_and_mark_anchors():
    deriver = SceneDeriver(TRAJ)
    out = [(topic, json.loads(data)) for m in run_messages() for topic, data in deriver.derive(m)]
    assert [t for t, _ in out] == [TOPIC_ESTIMATED, TOPIC_DESIRED] + [TOPIC_TRUE, TOPIC_ESTIMATED] * 2
    for _topic, scene in out:
        assert schema_errors(scene) == [], scene
        assert json.loads(json.dumps(scene, allow_nan=False)) == scene
        for e in scene["entities"]:
            assert e["frame_id"] == "world" and set(e["timestamp"]) == {"sec", "nsec"}
    # desired = configuration 2 of the trajectory, red, labelled
    *desired, legend = out[1][1]["entities"]
    assert [e["id"] for e in desired] == ["desired/0", "desired/1", "desired/2"]
    # the legend: one sample of every colour the scenes draw, each with its meaning, above the trajectory
    drawn = {json.dumps(p["color"], sort_keys=True) for _t, scene in out for e in scene["entities"] if e["id"] != "legend"
             for p in e["spheres"]}
    samples = [json.dumps(p["color"], sort_keys=True) for p in legend["spheres"]]
    assert legend["id"] == "legend" and drawn <= set(samples) and len(legend["texts"]) == len(samples)
    assert any("anchor" in t["text"] for t in legend["texts"]) and len(legend["lines"]) == 1  # the anchor's ring
    assert min(p["pose"]["position"]["y"] for p in legend["spheres"]) > 0.3  # above every desired position
    centres = [(e["spheres"][0]["pose"]["position"]["x"], e["spheres"][0]["pose"]["position"]["y"]) for e in desired]
    assert centres == [(0.6, 0.1), (0.8, 0.1), (0.6, 0.3)]
    assert desired[0]["spheres"][0]["color"]["r"] > 0.5 and [e["texts"][0]["text"] for e in desired] == ["0", "1", "2"]
    # step 0: no plan, nobody marked; step 1: robot 0 moves, 1 and 2 are anchors; step 2: 0 is the anchor
    def anchors(scene):
        return [e["id"] for e in scene["entities"] if e["lines"]]
    assert anchors(out[0][1]) == []
    assert anchors(out[3][1]) == ["estimated/1", "estimated/2"]
    assert anchors(out[5][1]) == ["estimated/0"]
    ring = out[3][1]["entities"][1]["lines"][0]
    assert ring["type"] == 1 and len(ring["points"]) >= 8
    # true positions: one blue entity per robot, from each step's truth set
    true = out[4][1]["entities"]
    assert [e["id"] for e in true] == ["true/0", "true/1", "true/2"] and true[0]["spheres"][0]["color"]["b"] > 0.5
    assert [e["spheres"][0]["pose"]["position"]["x"] for e in true] == [0.2, 1.2, 2.2]
    # without truth sets (single truths only) the latest truths come with each estimate
    lone = SceneDeriver(TRAJ)
    out2 = [pair for m in run_messages() if not isinstance(m, TruthSetMessage) for pair in lone.derive(m)]
    assert [t for t, _ in out2] == [TOPIC_ESTIMATED, TOPIC_DESIRED] + [TOPIC_ESTIMATED, TOPIC_TRUE] * 2
    # the validator does catch mistakes
    bad = json.loads(estimated_scene(run_messages()[0]))
    del bad["entities"][0]["frame_id"]
    bad["entities"][1]["spheres"][0]["color"]["r"] = "red"
    assert len(schema_errors(bad)) == 2
    assert trajectory_configurations({"robots": [0], "configurations": [[[1.0]]]}) is None
    assert trajectory_configurations(None) is None


def test_a_lost_robot_turns_grey_and_labelled_at_its_last_estimate():
    deriver = SceneDeriver(TRAJ)
    for m in run_messages():
        deriver.derive(m)
    out = deriver.derive(RobotEvent(run=RUN, step=2, robot=1, kind="lost", reason="liveliness token gone"))
    assert [t for t, _ in out] == [TOPIC_ESTIMATED]
    scene = json.loads(out[0][1])
    assert schema_errors(scene) == []
    (lost,) = scene["entities"]
    assert lost["id"] == "estimated/1" and lost["texts"][0]["text"] == "1 lost"
    position = lost["spheres"][0]["pose"]["position"]
    assert (position["x"], position["y"]) == (1.2, 0.01)  # robot 1's estimate after step 2
    color = lost["spheres"][0]["color"]
    assert color["r"] == color["g"] == color["b"] == 0.5
    assert deriver.derive(RobotEvent(run=RUN, step=2, robot=7, kind="lost", reason="never estimated")) == []


def _channels(path):
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        summary = reader.get_summary()
        msgs = [(ch.topic, m.data, m.log_time, m.publish_time, m.sequence) for _s, ch, m in reader.iter_messages(log_time_order=False)]
        return summary, msgs


def test_recording_writes_derived_channels_and_keeps_raw_ones_identical(tmp_path):
    msgs = [(message_key(m), encode(m)) for m in run_messages()] + sample_messages()
    paths, recs = {}, {}
    for foxglove in (True, False):
        paths[foxglove] = tmp_path / f"fox{foxglove}.mcap"
        with McapRecorder(paths[foxglove], RUN, {"trajectory": TRAJ}, foxglove=foxglove) as rec:
            recs[foxglove] = rec
            for i, (key, payload) in enumerate(msgs):
                rec.write(key, payload, log_time_ns=1_700_000_000_000_000_000 + i * 1000)
        assert rec.count == len(msgs)
    summary, got = _channels(paths[True])
    _, plain = _channels(paths[False])
    raw = [m for m in got if not is_derived(m[0])]
    assert raw == plain  # topics, payload bytes, log/publish times and sequence numbers unchanged
    assert [(k, p) for k, p, *_ in raw] == msgs

    derived = [m for m in got if m[0].startswith("/foxglove/")]
    # 6 estimates, 2 truth sets, 4 plans (configurations 2 and 1 of TRAJ): one derived message each;
    # single truths are not decoded by the recorder
    topics = {t for t, *_ in derived}
    assert topics == {TOPIC_ESTIMATED, TOPIC_TRUE, TOPIC_DESIRED}
    scene_counts = {t: n for t, n in recs[True].derived_counts().items() if t.startswith("/foxglove/")}
    assert scene_counts == {TOPIC_ESTIMATED: 6, TOPIC_TRUE: 2, TOPIC_DESIRED: 4}
    assert scene_counts == {t: sum(1 for m in derived if m[0] == t) for t in topics}
    assert recs[False].derived_counts() == {} and recs[True].derived_errors == 0
    schemas = {s.id: s for s in summary.schemas.values()}
    for ch in summary.channels.values():
        if ch.topic.startswith("/foxglove/"):
            assert ch.message_encoding == "json"
            assert schemas[ch.schema_id].name == "foxglove.SceneUpdate" and schemas[ch.schema_id].encoding == "jsonschema"
            assert json.loads(schemas[ch.schema_id].data) == SCENE_UPDATE_SCHEMA
    for topic, data, _log_time, _publish_time, _seq in derived:
        scene = json.loads(data)
        assert schema_errors(scene) == [], (topic, scene)
        assert scene["entities"] and all(e["frame_id"] == "world" for e in scene["entities"])
    # each derived message follows the raw one it comes from, with that message's log time
    keys = [m[0] for m in got]
    first_plan = keys.index(f"swarm/{RUN}/coord/plan")
    assert keys[first_plan + 1] == TOPIC_DESIRED and got[first_plan + 1][2] == got[first_plan][2]

    assert list(read_messages(paths[True])) == list(read_messages(paths[False]))
    assert len(list(read_messages(paths[True], derived=True))) == len(got)
    info = recording_info(paths[True])
    all_derived = [m for m in got if is_derived(m[0])]
    assert info["undecodable"] == 1 and info["derived_messages"] == len(all_derived) > len(derived)
    assert info["metadata"]["recorder"]["derived_messages"] == len(all_derived)
    out = tmp_path / "copy.mcap"
    assert recover(paths[True], out)["messages"] == len(got)
    assert _channels(out)[1] == got


def test_live_view_needs_the_extra(monkeypatch):
    from runtime.recording.foxglove_live import LiveView

    monkeypatch.setitem(sys.modules, "foxglove", None)  # import foxglove -> ImportError
    with pytest.raises(SwarmInputError, match=r"pip install -e '\.\[foxglove\]'"):
        LiveView(port=0)


def test_live_view_serves_a_websocket():
    pytest.importorskip("foxglove")
    from runtime.recording.foxglove_live import LiveView

    view = LiveView(port=0, host="127.0.0.1", trajectory=TRAJ)  # the port the server got
    port = view.port
    try:
        assert port > 0 and view.url == f"ws://127.0.0.1:{port}"
        for m in run_messages():
            view.handle(message_key(m), encode(m))
        view.handle(f"swarm/{RUN}/coord/estimate", b"\xc1 not msgpack")
        view.handle("not/a/swarm/key", b"")
        assert view.handled == len(run_messages()) and view.dropped == 2
        with socket.create_connection(("127.0.0.1", port), timeout=5) as conn:
            key = base64.b64encode(os.urandom(16)).decode()
            conn.sendall((f"GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                          f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n"
                          "Sec-WebSocket-Protocol: foxglove.sdk.v1\r\n\r\n").encode())
            reply = conn.recv(4096).decode(errors="replace")
            assert reply.startswith("HTTP/1.1 101"), reply
    finally:
        view.close()
    view.close()  # idempotent
    view.handle(message_key(run_messages()[0]), encode(run_messages()[0]))  # ignored after close


def test_bench_record_prints_json(capsys):
    from swarm_cli.main import main

    assert main(["bench", "record", "--robots", "4,6", "--steps", "3", "--repeats", "1", "--step-ms", "20,100", "--json"]) == 0
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    rows = out["results"]
    assert [(r["robots"], r["derived"]) for r in rows] == [(4, False), (4, True), (6, False), (6, True)]
    assert [r["step_ms"] for r in rows] == [20, 20, 100, 100]
    # messages per step, from the step it builds: per mover (half the robots) a command and two
    # statuses, per robot an observe request, a truth and an observation report, one truth set, one
    # estimate; one plan in the first of every 4 steps. N = 4: (2 x 3 + 4 x 3 + 2) x 3 + 1 = 61 over
    # 3 steps = 20.3; N = 6: (3 x 3 + 6 x 3 + 2) x 3 + 1 = 88 -> 29.3.
    assert [r["msgs_per_step"] for r in rows] == [20.3, 20.3, 29.3, 29.3]
    for plain, derived in (rows[0:2], rows[2:4]):
        assert plain["payload_mb"] == derived["payload_mb"] > 0  # the same raw messages in both modes
        assert plain["derived_msgs"] == 0 < derived["derived_msgs"]
        assert derived["file_mb"] > plain["file_mb"]  # the derived channels are in the file
    for r in rows:
        assert r["overhead_pct"] == pytest.approx(100 * r["record_ms_per_step"] / r["step_ms"], rel=0.01, abs=0.01)
        assert r["record_ms_per_step"] == pytest.approx(r["cpu_us_per_msg"] * r["msgs_per_step"] / 1e3, rel=0.01, abs=1e-3)
        assert r["msgs_per_s"] > 0 and r["mb_per_s"] >= 0


def test_failed_handshakes_are_logged_once(caplog):
    pytest.importorskip("foxglove")
    import logging
    import time

    from runtime.recording.foxglove_live import SERVER_LOGGER, LiveView

    with caplog.at_level(logging.INFO, logger=SERVER_LOGGER), LiveView(port=0) as view:
        for _ in range(4):  # plain HTTP, no WebSocket upgrade: each fails the handshake
            with socket.create_connection(("127.0.0.1", view.port), timeout=5) as conn:
                conn.sendall(b"GET / HTTP/1.1\r\nHost: x\r\n\r\n")
                conn.recv(4096)
        deadline = time.monotonic() + 10
        while view.failed_handshakes < 4 and time.monotonic() < deadline:
            time.sleep(0.02)
        assert view.failed_handshakes == 4
    failures = [r for r in caplog.records if "handshake" in r.getMessage()]
    assert len(failures) == 1 and failures[0].levelno == logging.WARNING
    assert "Foxglove" in failures[0].getMessage()
