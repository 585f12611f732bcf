"""A recording as a ROS 2 bag (rosbag2, MCAP storage, CDR) with standard messages (optional extra ``ros2``).

    export_ros2("recordings/sample.mcap", "out/sample-ros2", distro="humble")   # metadata.yaml + one .mcap

Written with ``rosbags`` (pure Python, no ROS install) for one ROS 2 distribution (``DISTROS``):

* ``humble`` (the default; most labs run it): message definitions of ``Stores.ROS2_HUMBLE`` and
  ``metadata.yaml`` version 5, the newest Humble's rosbag2 (0.15.x) reads: topics'
  ``offered_qos_profiles`` as a YAML *string* of numeric policies, no ``type_description_hash``,
  ``custom_data`` or ``ros_distro``. (Version 9, Jazzy's, writes the profiles as a YAML list with
  policy names, which Humble rejects: "yaml-cpp: bad conversion", ros2/rosbag2#2013.)
* ``jazzy``: ``Stores.ROS2_JAZZY`` definitions and metadata version 9.

For Humble the bag is written as rosbag2 version 8 by ``rosbags`` (QoS as numeric YAML strings,
in the metadata and in the MCAP channels, as Humble reads them), then ``metadata.yaml`` is
rewritten as version 5 (``humble_metadata``); for Jazzy ``rosbags`` writes version 9 itself. Frame ``world``,
metres, z = 0; header stamps are the source message's ``stamp_ns``, bag times its log time. Topics (ROS 2 names cannot have a token starting with a
digit, hence ``robot_<id>``):

* ``/tf_static`` ``tf2_msgs/msg/TFMessage``: one identity transform ``map`` -> ``world`` at the
  bag's start, offered transient-local (latched), so RViz's default fixed frame ``map`` shows the
  run without setting anything.
* ``/swarm/estimate`` ``geometry_msgs/msg/PoseArray``: every robot's estimated pose (ids order).
* ``/robot_<id>/pose`` ``geometry_msgs/msg/PoseWithCovarianceStamped``: robot ``id``'s estimate
  with its covariance (x, y and yaw rows/columns of the 6x6 row-major matrix filled from the
  3x3 (x, y, heading) covariance; z, roll and pitch rows 0).
* ``/swarm/truth`` ``geometry_msgs/msg/PoseArray``: true poses (simulated runs), ids order.
* ``/swarm/markers`` ``visualization_msgs/msg/MarkerArray``: spheres, namespaces ``estimated``
  (green), ``true`` (blue) and ``desired`` (red, from the plan's configuration and the
  trajectory metadata), marker id = robot id, so each array replaces the previous one.
* ``/swarm/localization_error`` ``std_msgs/msg/Float64``: e_l (Eq. 8, m) of each step with truth.
* ``/swarm/plan`` and ``/swarm/event`` ``std_msgs/msg/String``: the plan and robot events as JSON.

``rosbags`` is imported only here; without it ``export_ros2`` raises ``SwarmInputError``
naming the extra to install.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from runtime.errors import OptionError, SwarmInputError
from runtime.recording.foxglove_scene import trajectory_configurations
from runtime.recording.mcap_log import read_messages, recording_info
from runtime.wire.messages import EstimateMessage, MessageError, PlanMessage, RobotEvent, TruthSetMessage, decode

INSTALL_HINT = "pip install -e '.[ros2]'"
DISTROS = {"humble": 5, "jazzy": 9}  # ROS 2 distribution -> the rosbag2 metadata version written for it
DEFAULT_DISTRO = "humble"
FRAME = "world"
PARENT_FRAME = "map"  # RViz's default fixed frame: /tf_static ties it to FRAME
TF_STATIC = "/tf_static"
TF_TYPE = "tf2_msgs/msg/TFMessage"
SPHERE_M = 0.05
COLORS = {"estimated": (0.1, 0.75, 0.2, 0.9), "true": (0.15, 0.35, 0.95, 0.9), "desired": (0.9, 0.1, 0.1, 0.6)}
TOPICS = {
    "/swarm/estimate": "geometry_msgs/msg/PoseArray",
    "/swarm/truth": "geometry_msgs/msg/PoseArray",
    "/swarm/markers": "visualization_msgs/msg/MarkerArray",
    "/swarm/localization_error": "std_msgs/msg/Float64",
    "/swarm/plan": "std_msgs/msg/String",
    "/swarm/event": "std_msgs/msg/String",
}
ROBOT_TOPIC = "/robot_{}/pose"
ROBOT_TYPE = "geometry_msgs/msg/PoseWithCovarianceStamped"


def _rosbags(distro: str) -> Any:
    try:
        from rosbags.rosbag2 import StoragePlugin, Writer  # noqa: PLC0415 - optional dependency
        from rosbags.typesys import Stores, get_typestore  # noqa: PLC0415
    except ImportError as exc:
        raise SwarmInputError(f"swarm export --ros2 needs rosbags, which is not installed ({exc}): {INSTALL_HINT}") from None
    return StoragePlugin, Writer, get_typestore(Stores.ROS2_HUMBLE if distro == "humble" else Stores.ROS2_JAZZY)


def _latched() -> Any:
    """The QoS ``/tf_static`` is offered with: reliable, transient local, keep last 1 (as tf2's static broadcaster)."""
    from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime  # noqa: PLC0415

    zero = QosTime(sec=0, nsec=0)
    return Qos(QosHistory.KEEP_LAST, 1, QosReliability.RELIABLE, QosDurability.TRANSIENT_LOCAL, zero, zero,
               QosLiveliness.AUTOMATIC, zero, False)


HUMBLE_TOPIC_KEYS = ("name", "type", "serialization_format", "offered_qos_profiles")
HUMBLE_KEYS = ("version", "storage_identifier", "duration", "starting_time", "message_count", "topics_with_message_count",
               "compression_format", "compression_mode", "relative_file_paths", "files")


def humble_metadata(info: dict[str, Any]) -> dict[str, Any]:
    """``rosbag2_bagfile_information`` of version 8 (as ``rosbags`` writes it) as version 5: the fields Humble's
    ``rosbag2_storage`` decodes (``yaml.hpp`` of the humble branch), QoS profiles kept as their YAML string."""
    if info.get("version") != 8 or any(not isinstance(t["topic_metadata"].get("offered_qos_profiles"), str)
                                       for t in info["topics_with_message_count"]):
        raise ValueError("humble_metadata converts rosbag2 metadata version 8 (QoS profiles as YAML strings)")
    out = {k: info[k] for k in HUMBLE_KEYS}
    out["version"] = DISTROS["humble"]
    out["topics_with_message_count"] = [
        {"topic_metadata": {k: t["topic_metadata"][k] for k in HUMBLE_TOPIC_KEYS}, "message_count": t["message_count"]}
        for t in info["topics_with_message_count"]]
    return out


def _rewrite_for_humble(folder: Path) -> None:
    """Rewrite ``folder/metadata.yaml`` (version 8, as ``rosbags`` wrote it) as version 5 (``humble_metadata``)."""
    from ruamel.yaml import YAML  # noqa: PLC0415 - a dependency of rosbags

    yaml = YAML(typ="safe")
    yaml.default_flow_style = False
    path = folder / "metadata.yaml"
    info = humble_metadata(yaml.load(path.read_text())["rosbag2_bagfile_information"])
    with open(path, "w") as f:
        yaml.dump({"rosbag2_bagfile_information": info}, f)


class _Builder:
    """ROS 2 message objects of the typestore ``ts``."""

    def __init__(self, ts: Any) -> None:
        self.ts = ts
        t = ts.types
        self.Time, self.Header = t["builtin_interfaces/msg/Time"], t["std_msgs/msg/Header"]
        self.Pose, self.Point, self.Quaternion = t["geometry_msgs/msg/Pose"], t["geometry_msgs/msg/Point"], t["geometry_msgs/msg/Quaternion"]
        self.PoseArray, self.PoseWithCovariance = t["geometry_msgs/msg/PoseArray"], t["geometry_msgs/msg/PoseWithCovariance"]
        self.PoseWithCovarianceStamped = t[ROBOT_TYPE]
        self.Marker, self.MarkerArray = t["visualization_msgs/msg/Marker"], t["visualization_msgs/msg/MarkerArray"]
        self.Vector3, self.ColorRGBA = t["geometry_msgs/msg/Vector3"], t["std_msgs/msg/ColorRGBA"]
        self.Duration = t["builtin_interfaces/msg/Duration"]
        self.Float64, self.String = t["std_msgs/msg/Float64"], t["std_msgs/msg/String"]

    def header(self, stamp_ns: int) -> Any:
        sec, nsec = divmod(max(int(stamp_ns), 0), 1_000_000_000)
        return self.Header(stamp=self.Time(sec=sec, nanosec=nsec), frame_id=FRAME)

    def pose(self, x: float, y: float, heading: float = 0.0) -> Any:
        """A planar pose: yaw ``heading`` (rad) as a quaternion about z."""
        return self.Pose(position=self.Point(x=float(x), y=float(y), z=0.0),
                         orientation=self.Quaternion(x=0.0, y=0.0, z=math.sin(heading / 2), w=math.cos(heading / 2)))

    def static_frame(self, stamp_ns: int) -> Any:
        """``/tf_static``: the identity transform ``PARENT_FRAME`` -> ``FRAME``."""
        t = self.ts.types
        header = self.header(stamp_ns)
        header.frame_id = PARENT_FRAME
        transform = t["geometry_msgs/msg/Transform"](translation=self.Vector3(x=0.0, y=0.0, z=0.0),
                                                     rotation=self.Quaternion(x=0.0, y=0.0, z=0.0, w=1.0))
        return t[TF_TYPE](transforms=[t["geometry_msgs/msg/TransformStamped"](header=header, child_frame_id=FRAME,
                                                                              transform=transform)])

    def pose_array(self, stamp_ns: int, poses: Iterable[Sequence[float]]) -> Any:
        return self.PoseArray(header=self.header(stamp_ns), poses=[self.pose(*p) for p in poses])

    def pose_with_covariance(self, stamp_ns: int, pose: Sequence[float], cov: Sequence[Sequence[float]]) -> Any:
        full = np.zeros((6, 6))
        idx = (0, 1, 5)  # x, y, yaw in ROS's (x, y, z, roll, pitch, yaw)
        full[np.ix_(idx, idx)] = np.asarray(cov, float)
        return self.PoseWithCovarianceStamped(header=self.header(stamp_ns),
                                              pose=self.PoseWithCovariance(pose=self.pose(*pose), covariance=full.reshape(36)))

    def markers(self, stamp_ns: int, ns: str, positions: dict[int, tuple[float, float]]) -> Any:
        r, g, b, a = COLORS[ns]
        return self.MarkerArray(markers=[
            self.Marker(header=self.header(stamp_ns), ns=ns, id=int(robot) % 2**31, type=self.Marker.SPHERE, action=self.Marker.ADD,
                        pose=self.pose(x, y), scale=self.Vector3(x=SPHERE_M, y=SPHERE_M, z=SPHERE_M),
                        color=self.ColorRGBA(r=r, g=g, b=b, a=a), lifetime=self.Duration(sec=0, nanosec=0), frame_locked=False,
                        points=[], colors=[], texture_resource="", texture=self.ts.types["sensor_msgs/msg/CompressedImage"](
                            header=self.header(0), format="", data=_empty_bytes()),
                        uv_coordinates=[], text=str(int(robot)), mesh_resource="",
                        mesh_file=self.ts.types["visualization_msgs/msg/MeshFile"](filename="", data=_empty_bytes()),
                        mesh_use_embedded_materials=False)
            for robot, (x, y) in positions.items()])


def _empty_bytes() -> np.ndarray:
    return np.zeros(0, np.uint8)


def export_ros2(src: str | os.PathLike[str], out: str | os.PathLike[str], distro: str = DEFAULT_DISTRO) -> dict[str, Any]:
    """Write the recording ``src`` as a rosbag2 folder ``out`` (must not exist) for ROS 2 ``distro``;
    ``{"source", "path", "distro", "metadata_version", "messages", "topics", "complete", "bytes", "readable_bytes",
    "recorded_messages"}`` (an unfinished recording is exported up to its last complete record: ``complete`` False,
    ``readable_bytes`` of its ``bytes`` read). ``SwarmInputError`` (nothing written) when it holds no message of the run."""
    src, out = Path(src), Path(out)
    if distro not in DISTROS:
        raise OptionError("distro", f"{distro}: choose one of {', '.join(DISTROS)}")
    if out.exists():
        raise OptionError("ros2", f"{out}: already exists; rosbag2 writes a new folder")
    info = recording_info(src)  # SwarmInputError for what is not a readable recording
    if not info["raw_messages"]:
        raise SwarmInputError(f"{src}: nothing to export: no complete message of the run in it"
                              + ("" if info["complete"] else f" (unfinished: {info['problem']})"))
    StoragePlugin, Writer, ts = _rosbags(distro)
    build = _Builder(ts)
    configurations = trajectory_configurations(info["metadata"].get("run", {}).get("trajectory"))
    counts: dict[str, int] = {}
    out.parent.mkdir(parents=True, exist_ok=True)
    truths: dict[int, TruthSetMessage] = {}
    with Writer(out, version=8 if distro == "humble" else DISTROS[distro], storage_plugin=StoragePlugin.MCAP) as writer:
        connections: dict[str, Any] = {}

        def write(topic: str, msgtype: str, msg: Any, log_time: int) -> None:
            if topic not in connections:
                qos = (_latched(),) if topic == TF_STATIC else ()
                connections[topic] = writer.add_connection(topic, msgtype, typestore=ts, offered_qos_profiles=qos)
            writer.write(connections[topic], log_time, bytes(ts.serialize_cdr(msg, msgtype)))
            counts[topic] = counts.get(topic, 0) + 1

        for key, payload, log_time, _publish in read_messages(src):
            if TF_STATIC not in connections:  # the frames first, at the bag's start
                write(TF_STATIC, TF_TYPE, build.static_frame(log_time), log_time)
            try:
                msg = decode(payload, key=key)
            except MessageError:  # counted by swarm info; nothing to convert
                continue
            if isinstance(msg, EstimateMessage):
                write("/swarm/estimate", TOPICS["/swarm/estimate"], build.pose_array(msg.stamp_ns, msg.poses), log_time)
                for robot, pose, cov in zip(msg.ids, msg.poses, msg.cov, strict=True):
                    write(ROBOT_TOPIC.format(robot), ROBOT_TYPE, build.pose_with_covariance(msg.stamp_ns, pose, cov), log_time)
                write("/swarm/markers", TOPICS["/swarm/markers"],
                      build.markers(msg.stamp_ns, "estimated", {r: (p[0], p[1]) for r, p in zip(msg.ids, msg.poses, strict=True)}), log_time)
                truth = truths.pop(msg.step, None)
                if truth is not None:
                    true = dict(zip(truth.ids, truth.poses, strict=True))
                    errors = [math.dist(p[:2], true[r][:2]) for r, p in zip(msg.ids, msg.poses, strict=True) if r in true]
                    if errors:
                        write("/swarm/localization_error", TOPICS["/swarm/localization_error"],
                              build.Float64(data=sum(errors) / len(errors)), log_time)
            elif isinstance(msg, TruthSetMessage):
                truths = {msg.step: msg}  # the coordinator publishes a step's truth before its estimate
                write("/swarm/truth", TOPICS["/swarm/truth"], build.pose_array(msg.stamp_ns, msg.poses), log_time)
                write("/swarm/markers", TOPICS["/swarm/markers"],
                      build.markers(msg.stamp_ns, "true", {r: (p[0], p[1]) for r, p in zip(msg.ids, msg.poses, strict=True)}), log_time)
            elif isinstance(msg, PlanMessage):
                write("/swarm/plan", TOPICS["/swarm/plan"], build.String(data=json.dumps(
                    {"step": msg.step, "config": msg.config, "n_anchors": msg.n_anchors, "groups": [list(g) for g in msg.groups]})),
                      log_time)
                if configurations is not None and 1 <= msg.config <= len(configurations):
                    write("/swarm/markers", TOPICS["/swarm/markers"],
                          build.markers(msg.stamp_ns, "desired", configurations[msg.config - 1]), log_time)
            elif isinstance(msg, RobotEvent):
                write("/swarm/event", TOPICS["/swarm/event"], build.String(data=json.dumps(
                    {"step": msg.step, "robot": msg.robot, "kind": msg.kind, "reason": msg.reason})), log_time)
    if distro == "humble":
        _rewrite_for_humble(out)
    return {"source": str(src), "path": str(out), "distro": distro, "metadata_version": DISTROS[distro],
            "messages": sum(counts.values()), "topics": dict(sorted(counts.items())),
            "complete": info["complete"], "bytes": info["bytes"], "readable_bytes": info["readable_bytes"],
            "recorded_messages": info["raw_messages"]}
