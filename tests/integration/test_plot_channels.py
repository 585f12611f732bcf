"""Plottable JSON channels (runtime.recording.plot_channels): known answers, schemas, and what a recording holds."""

from __future__ import annotations

import json
import math

import pytest
from mcap.reader import make_reader

from runtime.recording.foxglove_scene import schema_errors
from runtime.recording.mcap_log import McapRecorder, recording_info
from runtime.recording.plot_channels import SCHEMAS, PlotDeriver, is_plot_topic
from runtime.wire.messages import EstimateMessage, RobotEvent, TruthSetMessage, encode, message_key
from tests.integration.test_foxglove import COV, RUN, TRAJ, run_messages


def _derive(messages) -> list[tuple[str, str, dict]]:
    deriver = PlotDeriver(TRAJ)
    return [(topic, schema, json.loads(data)) for m in messages for topic, schema, data in deriver.derive(m)]


def test_known_answers_of_a_small_run() -> None:
    out = _derive(run_messages())
    for topic, schema, body in out:
        assert schema_errors(body, SCHEMAS[schema]) == [], (topic, body)
        assert is_plot_topic(topic)
    est = {(b["step"], b["robot"]): b for t, _s, b in out if t.endswith("/estimate")}
    assert est[(0, 1)]["x"] == 0.2 and est[(0, 1)]["anchor"] == -1  # step 0: no plan yet
    assert est[(1, 0)]["std_x"] == pytest.approx(0.01) and est[(1, 0)]["std_heading"] == pytest.approx(math.sqrt(1e-3))
    # the plan moves [0] at step 1, [1, 2] at step 2
    assert [est[(1, r)]["anchor"] for r in range(3)] == [0, 1, 1]
    assert [est[(2, r)]["anchor"] for r in range(3)] == [1, 0, 0]
    err = {k: b for k, b in est.items() if "localization_m" in b}
    assert set(err) == {(s, r) for s in (1, 2) for r in range(3)}  # steps with both estimate and truth
    assert "true_x" not in est[(0, 0)]  # no truth of step 0 in this run
    e = err[(1, 0)]  # estimate (0.1, 0.01), truth (0.1, 0), desired of configuration 2: (0.6, 0.1)
    assert e["localization_m"] == pytest.approx(0.01) and e["dx"] == pytest.approx(0.0) and e["dy"] == pytest.approx(0.01)
    assert e["config"] == 2 and e["following_m"] == pytest.approx(math.hypot(0.5, 0.1))
    assert (e["true_x"], e["true_y"], e["true_heading"]) == (pytest.approx(0.1), 0.0, 0.0)
    swarm = [b for t, _s, b in out if t == "/swarm/error"]
    assert [b["step"] for b in swarm] == [1, 2]
    assert swarm[0]["localization_mean_m"] == pytest.approx(0.01) and swarm[0]["std_mean_m"] == pytest.approx(math.sqrt(2e-4))
    desired = [(0.6, 0.1), (0.8, 0.1), (0.6, 0.3)]
    truth = [(0.1 + r, 0.0) for r in range(3)]
    follow = [math.dist(t, d) for t, d in zip(truth, desired, strict=True)]
    assert swarm[0]["following_mean_m"] == pytest.approx(sum(follow) / 3) and swarm[0]["following_max_m"] == pytest.approx(max(follow))
    plan = [b for t, _s, b in out if t == "/swarm/plan"]
    assert plan == [{"step": 1, "config": 2, "n_anchors": 2, "steps": 2, "moving": 1, "anchors": [1, 2]}]
    assert [(err[(s, 2)]["true_x"], err[(s, 2)]["true_y"]) for s in (1, 2)] == [(pytest.approx(2.1), 0.0), (pytest.approx(2.2), 0.0)]
    assert {t for t, _s, _b in out} == {f"/robot/{r}/estimate" for r in range(3)} | {"/swarm/error", "/swarm/plan"}
    assert len(out) == 3 * 3 + 2 + 1  # one message per robot and estimate, one swarm error per step with truth, one plan


def test_a_truth_after_its_estimate_gives_the_same_last_word() -> None:
    msgs = run_messages()
    swapped = list(msgs)
    for i, m in enumerate(swapped[:-1]):  # every truth set after the estimate of its step
        if isinstance(m, TruthSetMessage) and isinstance(swapped[i + 1], EstimateMessage):
            swapped[i], swapped[i + 1] = swapped[i + 1], m
    assert swapped != msgs

    def last(out):  # the last message per topic and step: what a plot shows
        return {(t, b["step"]): b for t, _s, b in out}

    late = _derive(swapped)
    assert last(late) == last(_derive(msgs))
    # without the truth first, each estimate is written once without and once with its truth
    assert sum(1 for t, _s, _b in late if t == "/robot/0/estimate") == 1 + 2 * 2


def test_robot_events_and_a_truth_that_never_comes() -> None:
    lost = RobotEvent(run=RUN, step=3, robot=2, kind="lost", reason="liveliness token gone")
    back = RobotEvent(run=RUN, step=5, robot=2, kind="rejoined", reason="")
    out = _derive([lost, back])
    assert [(t, b["robot"], b["kind"], b["lost"]) for t, _s, b in out] == [("/swarm/event", 2, "lost", 1), ("/swarm/event", 2, "rejoined", 0)]
    assert out[0][2]["reason"] == "liveliness token gone"
    # estimates without truth (hardware): estimates only, and nothing kept beyond a few steps
    deriver = PlotDeriver(TRAJ)
    for step in range(20):
        est = EstimateMessage(run=RUN, step=step, ids=[0, 1, 2], poses=[[0, 0, 0]] * 3, cov=COV)
        out = deriver.derive(est)
        assert {t for t, _s, _b in out} == {f"/robot/{r}/estimate" for r in range(3)}
        assert all("localization_m" not in json.loads(b) for _t, _s, b in out)
    assert len(deriver.estimates) <= 4


def test_a_recording_holds_plottable_json_channels_with_their_schemas(tmp_path) -> None:
    jsonschema = pytest.importorskip("jsonschema")  # an independent validator (dev extra)
    msgs = [*run_messages(), RobotEvent(run=RUN, step=2, robot=1, kind="lost", reason="no answer")]
    path = tmp_path / "plot.mcap"
    with McapRecorder(path, RUN, {"trajectory": TRAJ}) as rec:
        for m in msgs:
            rec.write(message_key(m), encode(m))
    seen: dict[str, int] = {}
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            if not is_plot_topic(channel.topic):
                continue
            assert channel.message_encoding == "json" and schema.encoding == "jsonschema"
            body = json.loads(message.data)
            jsonschema.validate(body, json.loads(schema.data))
            assert all(isinstance(v, (int, float, str, list)) for v in body.values())  # flat: a plot path is topic.field
            seen[channel.topic] = seen.get(channel.topic, 0) + 1
    assert seen["/robot/0/estimate"] == 3 and seen["/swarm/event"] == 1
    assert seen["/swarm/plan"] == 1 and seen["/swarm/error"] == 2
    info = recording_info(path)
    assert info["raw_messages"] == len(msgs) and info["derived_messages"] == info["messages"] - len(msgs)
    for schema_name, schema in SCHEMAS.items():
        jsonschema.Draft202012Validator.check_schema(schema)
        assert schema["title"] == schema_name
