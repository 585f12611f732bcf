"""A recording as a ROS 2 bag (rosbag2, MCAP storage, CDR) with standard messages (optional extra ``ros2``).

    export_ros2("recordings/sample.mcap", "out/sample-ros2")   # a rosbag2 folder: metadata.yaml + one .mcap

Written with ``rosbags`` (pure Python, no ROS install), message definitions of ROS 2 Jazzy
(``Stores.ROS2_JAZZY``; the messages used are the same in Humble), rosbag2 metadata
version 9. Frame ``world``, metres, z = 0; header stamps are the source message's
``stamp_ns``, bag times its log time. Topics (ROS 2 names cannot have a token starting with a
digit, hence ``robot_<id>``):

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
from pathlib import Path
from typing import Any

import numpy as np

from runtime.errors import SwarmInputError
from runtime.recording.foxglove_scene import trajectory_configurations
from runtime.recording.mcap_log import read_messages, recording_info
from runtime.wire.messages import EstimateMessage, MessageError, PlanMessage, RobotEvent, TruthSetMessage, decode

INSTALL_HINT = "pip install -e '.[ros2]'"
FRAME = "world"
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


def _rosbags() -> Any:
    try:
        from rosbags.rosbag2 import StoragePlugin, Writer  # noqa: PLC0415 - optional dependency
        from rosbags.typesys import Stores, get_typestore  # noqa: PLC0415
    except ImportError as exc:
        raise SwarmInputError(f"swarm export --ros2 needs rosbags, which is not installed ({exc}): {INSTALL_HINT}") from None
    return StoragePlugin, Writer, get_typestore(Stores.ROS2_JAZZY)


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

    def pose_array(self, stamp_ns: int, poses) -> Any:
        return self.PoseArray(header=self.header(stamp_ns), poses=[self.pose(*p) for p in poses])

    def pose_with_covariance(self, stamp_ns: int, pose, cov) -> Any:
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


def export_ros2(src: str | os.PathLike, out: str | os.PathLike) -> dict[str, Any]:
    """Write the recording ``src`` as a rosbag2 folder ``out`` (must not exist); ``{"path", "messages", "topics"}``."""
    src, out = Path(src), Path(out)
    if out.exists():
        raise SwarmInputError(f"--ros2 {out}: already exists; rosbag2 writes a new folder")
    info = recording_info(src)  # SwarmInputError for what is not a readable recording
    StoragePlugin, Writer, ts = _rosbags()
    build = _Builder(ts)
    configurations = trajectory_configurations(info["metadata"].get("run", {}).get("trajectory"))
    counts: dict[str, int] = {}
    out.parent.mkdir(parents=True, exist_ok=True)
    truths: dict[int, TruthSetMessage] = {}
    with Writer(out, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        connections: dict[str, Any] = {}

        def write(topic: str, msgtype: str, msg: Any, log_time: int) -> None:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=ts)
            writer.write(connections[topic], log_time, bytes(ts.serialize_cdr(msg, msgtype)))
            counts[topic] = counts.get(topic, 0) + 1

        for key, payload, log_time, _publish in read_messages(src):
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
    return {"source": str(src), "path": str(out), "messages": sum(counts.values()), "topics": dict(sorted(counts.items()))}
