"""``swarm export --ros2``: the rosbag2 is read back with mcap-ros2-support's decoder (we write with rosbags)."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from runtime.errors import SwarmInputError
from runtime.models.metrics import localization_error
from runtime.recording.mcap_log import read_messages
from runtime.wire.messages import EstimateMessage, PlanMessage, TruthSetMessage, decode
from swarm_cli.main import main

SAMPLE = Path(__file__).resolve().parents[2] / "recordings" / "sample.mcap"


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


def _humble_parses(info: dict) -> None:
    """Assert what Humble's rosbag2 (``rosbag2_storage``'s ``yaml.hpp`` and ``rosbag2_transport``'s ``qos.cpp``
    of the humble branch) requires of ``rosbag2_bagfile_information``, field by field, with yaml-cpp's types."""
    def is_uint(v) -> bool:
        return isinstance(v, int) and not isinstance(v, bool) and v >= 0

    assert info["version"] == 5  # Humble's BagMetadata::version; its decoder reads every field up to version 5
    assert isinstance(info["storage_identifier"], str) and info["storage_identifier"] == "mcap"
    assert is_uint(info["duration"]["nanoseconds"]) and is_uint(info["starting_time"]["nanoseconds_since_epoch"])
    assert is_uint(info["message_count"])
    assert isinstance(info["relative_file_paths"], list) and all(isinstance(p, str) for p in info["relative_file_paths"])
    assert isinstance(info["compression_format"], str) and isinstance(info["compression_mode"], str)  # version >= 3
    for f in info["files"]:  # version >= 5
        assert isinstance(f["path"], str) and is_uint(f["message_count"])
        assert is_uint(f["starting_time"]["nanoseconds_since_epoch"]) and is_uint(f["duration"]["nanoseconds"])
    from ruamel.yaml import YAML

    for t in info["topics_with_message_count"]:
        meta = t["topic_metadata"]
        assert is_uint(t["message_count"])
        assert all(isinstance(meta[k], str) for k in ("name", "type", "serialization_format"))
        qos = meta["offered_qos_profiles"]
        assert isinstance(qos, str)  # version >= 4: as<std::string>(); a YAML list here is Jazzy's "bad conversion"
        for profile in YAML(typ="safe").load(qos) or []:  # Rosbag2QoS decode: ints, not policy names
            for key in ("history", "reliability", "durability", "liveliness", "depth"):
                assert isinstance(profile[key], int) and not isinstance(profile[key], bool), (key, profile)
            for key in ("deadline", "lifespan", "liveliness_lease_duration"):
                assert is_uint(profile[key]["sec"]) and is_uint(profile[key]["nsec"])
            assert isinstance(profile["avoid_ros_namespace_conventions"], bool)
        assert set(meta) == {"name", "type", "serialization_format", "offered_qos_profiles"}  # nothing of later versions


def _metadata(folder: Path) -> dict:
    from ruamel.yaml import YAML

    return YAML(typ="safe").load((folder / "metadata.yaml").read_text())["rosbag2_bagfile_information"]


@pytest.mark.parametrize("distro, version", [("humble", 5), ("jazzy", 9)])
def test_export_for_each_ros2_distro_parses_as_that_distro_does(tmp_path, distro, version) -> None:
    """The bag's metadata is what the distribution's rosbag2 parses (checked field by field for Humble; read with
    ``rosbags``, which parses every metadata version, for both); /tf_static ties RViz's default frame to ours, latched."""
    pytest.importorskip("rosbags")
    from rosbags.interfaces import QosDurability
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    out = tmp_path / distro
    args = ["export", str(SAMPLE), "--ros2", str(out), "--json"] + ([] if distro == "humble" else ["--distro", distro])
    proc = subprocess.run([sys.executable, "-m", "swarm_cli.main", *args], capture_output=True, text=True,
                                        timeout=120, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    assert result["distro"] == distro and result["metadata_version"] == version
    info = _metadata(out)
    assert info["version"] == version
    if distro == "humble":
        _humble_parses(info)
    else:
        assert all(isinstance(t["topic_metadata"]["offered_qos_profiles"], list) for t in info["topics_with_message_count"])
        assert all(t["topic_metadata"]["type_description_hash"].startswith("RIHS01_") for t in info["topics_with_message_count"])
    ts = get_typestore(Stores.ROS2_HUMBLE if distro == "humble" else Stores.ROS2_JAZZY)
    with Reader(out) as reader:
        assert reader.message_count == result["messages"] == info["message_count"]
        (tf,) = [c for c in reader.connections if c.topic == "/tf_static"]
        (qos,) = tf.ext.offered_qos_profiles
        assert qos.durability == QosDurability.TRANSIENT_LOCAL and tf.msgtype == "tf2_msgs/msg/TFMessage"
        first = next(reader.messages())
        assert first[0].topic == "/tf_static"  # at the bag's start, before any pose
        (transform,) = ts.deserialize_cdr(first[2], first[0].msgtype).transforms
        assert (transform.header.frame_id, transform.child_frame_id) == ("map", "world")
        assert transform.transform.rotation.w == 1.0 and transform.transform.translation.x == 0.0
        poses = [ts.deserialize_cdr(raw, c.msgtype) for c, _t, raw in reader.messages() if c.topic == "/swarm/estimate"]
    assert len(poses) == len(_recorded(EstimateMessage)) and poses[0].header.frame_id == "world"


def test_humble_metadata_refuses_what_it_cannot_convert() -> None:
    from runtime.recording.ros2_export import humble_metadata

    with pytest.raises(ValueError, match="version 8"):
        humble_metadata({"version": 9, "topics_with_message_count": []})


def test_foxglove_layout_for_the_runs_robots(tmp_path) -> None:
    from runtime.recording.foxglove_layout import MAX_PLOTTED, layout

    assert main(["export", str(SAMPLE), "--foxglove-layout", str(tmp_path / "l.json")]) == 0
    written = json.loads((tmp_path / "l.json").read_text())
    paths = [p["value"] for p in written["configById"]["Plot!robots"]["paths"]]
    assert paths == [f"/robot/{r}/estimate.localization_m" for r in range(10)]
    target = written["configById"]["3D!swarm"]["cameraState"]["targetOffset"]
    xy = np.array(_sample_meta()["trajectory"]["configurations"]).reshape(-1, 2)
    assert np.allclose(target[:2], (xy.max(axis=0) + xy.min(axis=0)) / 2, atol=1e-3)
    big = layout(range(100, 160))
    for panel in ("Plot!robots", "Plot!uncertainty"):
        assert len(big["configById"][panel]["paths"]) == MAX_PLOTTED
        assert f"the first {MAX_PLOTTED} of 60 robots" in big["configById"][panel]["title"]
    assert json.loads((Path(__file__).resolve().parents[2] / "docs" / "foxglove-layout.json").read_text()) == layout(range(10))


def _sample_meta() -> dict:
    from runtime.recording.mcap_log import recording_info

    return recording_info(SAMPLE)["metadata"]["run"]


def test_foxglove_layout_of_the_ros2_bag_refers_to_its_topics_and_fields(tmp_path) -> None:
    """With --ros2, --foxglove-layout describes the bag: every plotted path names a topic of the bag and a field
    its messages have (resolved on a message read back), one line per robot of the run."""
    pytest.importorskip("rosbags")
    import re

    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    bag, out = tmp_path / "bag", tmp_path / "layout.json"
    assert main(["export", str(SAMPLE), "--ros2", str(bag), "--foxglove-layout", str(out)]) == 0
    config = json.loads(out.read_text())["configById"]
    ts = get_typestore(Stores.ROS2_HUMBLE)
    first: dict[str, object] = {}
    with Reader(bag) as reader:
        for c, _t, raw in reader.messages():
            first.setdefault(c.topic, ts.deserialize_cdr(raw, c.msgtype))
    paths = [p["value"] for panel in config.values() for p in panel.get("paths", [])]
    paths += [config[k]["topicPath"] for k in config if k.startswith("RawMessages!")]
    assert len([p for p in paths if p.startswith("/robot_")]) == 2 * 10
    for path in paths:
        topic, _, field = path.partition(".")
        if topic == "/swarm/event":  # no robot was lost in the sample run
            continue
        assert topic in first, path
        value = first[topic]
        for name, index in re.findall(r"(\w+)(?:\[(\d+)\])?", field):
            value = getattr(value, name)
            value = value[int(index)] if index else value
        assert isinstance(value, (float, str)), path
    assert set(config["3D!swarm"]["topics"]) <= set(first)


def test_an_unfinished_recording_is_exported_with_a_warning_and_an_empty_one_refused(tmp_path, capsys) -> None:
    pytest.importorskip("rosbags")
    data = SAMPLE.read_bytes()
    cut = tmp_path / "killed.mcap"
    cut.write_bytes(data[: len(data) // 2])  # killed half way: the messages of the first complete records remain
    assert main(["export", str(cut), "--ros2", str(tmp_path / "bag"), "--json"]) == 0
    captured = capsys.readouterr()
    result = json.loads(captured.out.strip().splitlines()[-1])
    (warning,) = captured.err.strip().splitlines()
    assert warning.startswith(f"swarm export: warning: {cut} is unfinished") and f"{result['messages']} ROS 2 messages" in warning
    assert result["complete"] is False and 0 < result["recorded_messages"] < sum(1 for _ in read_messages(SAMPLE))
    assert f"first {result['readable_bytes']} of {len(data) // 2} bytes" in warning
    assert sum(_read_bag(tmp_path / "bag")[t].__len__() for t in result["topics"]) == result["messages"] > 0

    assert main(["export", str(cut), "--truth", str(tmp_path / "truth.csv")]) == 0
    assert "swarm export: warning:" in capsys.readouterr().err

    header_only = tmp_path / "header.mcap"
    header_only.write_bytes(data[:3000])  # no complete message of the run
    assert main(["export", str(header_only), "--ros2", str(tmp_path / "empty")]) == 2
    (error,) = capsys.readouterr().err.strip().splitlines()
    assert error.startswith(f"swarm export: error: {header_only}: nothing to export") and not (tmp_path / "empty").exists()

    assert main(["export", str(SAMPLE), "--ros2", str(tmp_path / "whole")]) == 0
    assert capsys.readouterr().err == ""  # a finished recording: no warning
