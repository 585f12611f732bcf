"""``swarm export --ros2``: the rosbag2 is read back with mcap-ros2-support's decoder (we write with rosbags)."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from runtime.errors import SwarmInputError
from runtime.models.metrics import localization_error
from runtime.recording.mcap_log import read_messages
from runtime.wire.messages import EstimateMessage, PlanMessage, TruthSetMessage, decode
from swarm_cli.main import main

SAMPLE = Path(__file__).resolve().parent.parent / "recordings" / "sample.mcap"


def _recorded(kind):
    return [m for k, p, _t, _pub in read_messages(SAMPLE) if isinstance(m := decode(p, key=k), kind)]


def _read_bag(folder: Path) -> dict[str, list]:
    mcap_ros2_decoder = pytest.importorskip("mcap_ros2.decoder")
    from mcap.reader import make_reader

    files = sorted(folder.glob("*.mcap"))
    assert len(files) == 1 and (folder / "metadata.yaml").exists()
    out: dict[str, list] = {}
    with open(files[0], "rb") as f:
        reader = make_reader(f, decoder_factories=[mcap_ros2_decoder.DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        for schema, channel, message, ros in reader.iter_decoded_messages(log_time_order=False):
            assert channel.message_encoding == "cdr" and schema.encoding == "ros2msg"
            out.setdefault(channel.topic, []).append((schema.name, message, ros))
    return out


def _yaw(q) -> float:
    return math.atan2(2 * (q.w * q.z + q.x * q.y), 1 - 2 * (q.y * q.y + q.z * q.z))


def test_export_ros2_round_trip(tmp_path, capsys) -> None:
    pytest.importorskip("rosbags")
    out = tmp_path / "bag"
    assert main(["export", str(SAMPLE), "--ros2", str(out), "--json"]) == 0
    result = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    bag = _read_bag(out)
    assert result["topics"] == {t: len(v) for t, v in bag.items()}
    estimates, truths, plans = _recorded(EstimateMessage), _recorded(TruthSetMessage), _recorded(PlanMessage)

    poses = bag["/swarm/estimate"]
    assert len(poses) == len(estimates) and {s for s, *_ in poses} == {"geometry_msgs/msg/PoseArray"}
    for (_s, _m, ros), est in zip(poses, estimates, strict=True):
        assert ros.header.frame_id == "world" and ros.header.stamp.sec * 10**9 + ros.header.stamp.nanosec == est.stamp_ns
        got = np.array([[p.position.x, p.position.y, _yaw(p.orientation)] for p in ros.poses])
        want = np.array(est.poses)
        assert np.allclose(got[:, :2], want[:, :2], rtol=0, atol=1e-12)
        assert np.allclose(np.angle(np.exp(1j * (got[:, 2] - want[:, 2]))), 0, atol=1e-9)

    robot3 = bag["/robot_3/pose"]
    assert {s for s, *_ in robot3} == {"geometry_msgs/msg/PoseWithCovarianceStamped"} and len(robot3) == len(estimates)
    for (_s, _m, ros), est in zip(robot3, estimates, strict=True):
        i = list(est.ids).index(3)
        cov = np.array(ros.pose.covariance).reshape(6, 6)
        assert np.array_equal(cov[np.ix_((0, 1, 5), (0, 1, 5))], np.array(est.cov[i]))
        assert cov[2, 2] == cov[3, 3] == cov[4, 4] == 0.0
        assert ros.pose.pose.position.x == est.poses[i][0]

    assert len(bag["/swarm/truth"]) == len(truths)
    by_step = {t.step: t for t in truths}
    errors = [ros.data for _s, _m, ros in bag["/swarm/localization_error"]]
    want = [float(localization_error(np.array(by_step[e.step].poses)[:, :2], np.array(e.poses)[:, :2]))
            for e in estimates if e.step in by_step]
    assert errors == pytest.approx(want, rel=1e-12)

    namespaces: dict[str, int] = {}
    for _s, _m, ros in bag["/swarm/markers"]:
        (ns,) = {m.ns for m in ros.markers}  # one kind per array
        assert all(m.type == 2 and m.header.frame_id == "world" for m in ros.markers)  # SPHERE
        namespaces[ns] = namespaces.get(ns, 0) + 1
    assert namespaces == {"estimated": len(estimates), "true": len(truths), "desired": len(plans)}
    assert [json.loads(ros.data)["config"] for _s, _m, ros in bag["/swarm/plan"]] == [p.config for p in plans]


def test_export_refuses_an_existing_folder_and_names_the_extra(tmp_path, monkeypatch, capsys) -> None:
    out = tmp_path / "exists"
    out.mkdir()
    assert main(["export", str(SAMPLE), "--ros2", str(out)]) == 2
    assert "--ros2" in capsys.readouterr().err
    from runtime.recording.ros2_export import export_ros2

    monkeypatch.setitem(sys.modules, "rosbags.rosbag2", None)  # import -> ImportError
    with pytest.raises(SwarmInputError, match=r"pip install -e '\.\[ros2\]'"):
        export_ros2(SAMPLE, tmp_path / "new")
    assert main(["export", str(tmp_path / "missing.mcap"), "--ros2", str(tmp_path / "x")]) == 2
