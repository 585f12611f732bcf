"""A run, live in ROS 2 (``swarm ros2 bridge``, ``swarm launch --ros2``; docs/ros2.md).

``Bridge`` subscribes the run's estimates, plans and robot events on Zenoh and publishes, on node
``/swarm/bridge`` (reliable, transient local: RViz2 or Foxglove joining late get the latest):

* ``/swarm/estimates`` (``geometry_msgs/PoseArray``, frame ``world``): every estimated pose, in id order;
* ``/swarm/robot<id>/pose`` (``geometry_msgs/PoseWithCovarianceStamped``): each robot's estimate and its
  (x, y, heading) covariance in the 6x6 layout (x, y, z, roll, pitch, yaw);
* ``/swarm/markers`` (``visualization_msgs/MarkerArray``): per robot a body (cylinder of the body radius;
  anchors of the step, the robots that stood still, orange, the others green, lost ones grey), an id label,
  its 2-sigma position covariance ellipse (95 % would be 2.45 sigma), and the desired configuration of the
  plan in progress (red spheres) when the trajectory is known;

and serves ``/swarm/estop`` (``std_srvs/Trigger``): the run-wide emergency stop of ``swarm estop``
(``coordinator.node.stop.emergency_stop``), answered with who acknowledged it (success: someone did).
The bridge ends when the run does: once a coordinator's token was seen and every one is gone.
"""

from __future__ import annotations

import logging
import math
import os
import threading
import time
from typing import Any, cast

import numpy as np

from runtime.models.trajectory import Trajectory
from runtime.wire.keys import coord_alive_key, coord_key, validate_run
from runtime.wire.messages import EstimateMessage, MessageError, PlanMessage, RobotEvent, decode
from runtime.wire.ros2 import RosProcess, qos, require_ros2, set_yaw, stamp
from runtime.wire.transport import subscribe, watch_liveliness

_log = logging.getLogger(__name__)
FRAME = "world"
SIGMAS = 2.0  # covariance ellipses drawn at 2 sigma
END_GRACE_S = 1.0  # the run is over this long after its last coordinator token went
GREEN, ORANGE, GREY, RED, WHITE = (0.1, 0.7, 0.2, 0.9), (1.0, 0.55, 0.0, 0.95), (0.5, 0.5, 0.5, 0.6), (0.9, 0.1, 0.1, 0.8), (1.0, 1.0, 1.0, 1.0)


def ellipse(cov_xy: np.ndarray, sigmas: float = SIGMAS, points: int = 32) -> np.ndarray:
    """Points (points + 1, 2) of the ``sigmas`` ellipse of a 2x2 position covariance, centred at 0 and closed."""
    vals, vecs = np.linalg.eigh(0.5 * (cov_xy + cov_xy.T))
    axes = sigmas * np.sqrt(np.clip(vals, 0.0, None))
    t = np.linspace(0.0, 2 * math.pi, points + 1)
    return cast(np.ndarray, (vecs @ (axes[:, None] * np.stack([np.cos(t), np.sin(t)]))).T)


def anchors_of(plan: PlanMessage | None, step: int, ids: np.ndarray) -> set[int]:
    """The robots that stood still in ``step`` of ``plan`` (none when the step is not of that plan)."""
    if plan is None or not plan.step <= step < plan.step + len(plan.groups):
        return set()
    return set(int(i) for i in ids) - set(plan.groups[step - plan.step])


class Bridge:
    """Publishes run ``run_id`` into ROS 2 (module doc); ``settings``: how the estop service reaches the run."""

    def __init__(self, session: Any, settings: Any, run_id: str, trajectory: Trajectory | None = None, robot_radius: float = 0.1) -> None:
        require_ros2("swarm ros2 bridge")
        from geometry_msgs.msg import Point, Pose, PoseArray, PoseWithCovarianceStamped  # noqa: PLC0415 - ROS 2 only here
        from std_srvs.srv import Trigger  # noqa: PLC0415
        from visualization_msgs.msg import Marker, MarkerArray  # noqa: PLC0415

        self._m = {"Point": Point, "Pose": Pose, "PoseArray": PoseArray, "PoseCov": PoseWithCovarianceStamped, "Marker": Marker,
                   "MarkerArray": MarkerArray}
        self.run_id, self.settings, self.traj, self.radius = validate_run(run_id), settings, trajectory, robot_radius
        self.published = 0  # estimates published
        self._plan: PlanMessage | None = None
        self._lost: set[int] = set()
        self._coords: set[str] = set()
        self._seen_coord = False
        self._gone_at: float | None = None
        self._done = threading.Event()
        self._lock = threading.Lock()
        self._node = RosProcess.add("bridge", "/swarm")
        latched = qos("reliable", 1, latched=True)
        self._estimates = self._node.create_publisher(PoseArray, "estimates", latched)
        self._markers = self._node.create_publisher(MarkerArray, "markers", latched)
        self._poses: dict[int, Any] = {}
        self._service = self._node.create_service(Trigger, "estop", self._on_estop)
        self._subs = [subscribe(session, coord_key(run_id, leaf), self.handle) for leaf in ("estimate", "plan", "event")]
        self._subs.append(watch_liveliness(session, coord_alive_key(run_id), self._on_coordinator))

    # -- Zenoh side ---------------------------------------------------------------------

    def _on_coordinator(self, key: str, alive: bool) -> None:
        with self._lock:
            if alive:
                self._coords.add(key)
                self._seen_coord, self._gone_at = True, None
            else:
                self._coords.discard(key)
                if not self._coords:
                    self._gone_at = time.monotonic()

    def wait(self, stop: threading.Event) -> None:
        """Until ``stop`` is set or the run is over (module doc)."""
        while not stop.wait(0.1):
            with self._lock:
                if self._seen_coord and self._gone_at is not None and time.monotonic() - self._gone_at > END_GRACE_S:
                    return

    def handle(self, key: str, payload: bytes) -> None:
        """One Zenoh message of the run (bad ones are logged and dropped)."""
        try:
            if key.endswith("/plan"):
                self._plan = decode(payload, PlanMessage, key=key)
            elif key.endswith("/event"):
                event = decode(payload, RobotEvent, key=key)
                (self._lost.add if event.kind == "lost" else self._lost.discard)(event.robot)
            else:
                self.publish(decode(payload, EstimateMessage, key=key))
        except MessageError as exc:
            _log.warning("bridge: dropped a message on %s: %s", key, exc)

    # -- ROS 2 side ---------------------------------------------------------------------

    def publish(self, est: EstimateMessage) -> None:
        """``/swarm/estimates``, the robots' poses and the markers of one estimate."""
        t = stamp(est.stamp_ns)
        ids, poses, cov = np.array(est.ids, dtype=np.int64), np.array(est.poses, float), np.array(est.cov, float)
        arr = self._m["PoseArray"]()
        arr.header.stamp, arr.header.frame_id = t, FRAME
        arr.poses = [self._pose(p) for p in poses]
        self._estimates.publish(arr)
        for robot, pose, c in zip(ids, poses, cov, strict=True):
            msg = self._m["PoseCov"]()
            msg.header.stamp, msg.header.frame_id = t, FRAME
            msg.pose.pose = self._pose(pose)
            full = np.zeros((6, 6))
            full[np.ix_([0, 1, 5], [0, 1, 5])] = c
            msg.pose.covariance = full.ravel().tolist()
            self._pose_pub(int(robot)).publish(msg)
        self._markers.publish(self._marker_array(t, est.step, ids, poses, cov))
        self.published += 1

    def _pose_pub(self, robot: int) -> Any:
        if robot not in self._poses:
            self._poses[robot] = self._node.create_publisher(self._m["PoseCov"], f"robot{robot}/pose", qos("reliable", 1, latched=True))
        return self._poses[robot]

    def _pose(self, pose: np.ndarray) -> Any:
        p = self._m["Pose"]()
        p.position.x, p.position.y = float(pose[0]), float(pose[1])
        set_yaw(p.orientation, float(pose[2]))
        return p

    def _marker(self, t: Any, ns: str, mid: int, kind: int, color: tuple[float, ...]) -> Any:
        m = self._m["Marker"]()
        m.header.stamp, m.header.frame_id, m.ns, m.id, m.type, m.action = t, FRAME, ns, mid, kind, 0
        m.color.r, m.color.g, m.color.b, m.color.a = color
        m.pose.orientation.w = 1.0
        return m

    def _marker_array(self, t: Any, step: int, ids: np.ndarray, poses: np.ndarray, cov: np.ndarray) -> Any:
        marker = self._m["Marker"]
        anchors = anchors_of(self._plan, step, ids)
        out = self._m["MarkerArray"]()
        for robot, pose, c in zip(ids, poses, cov, strict=True):
            r = int(robot)
            color = GREY if r in self._lost else ORANGE if r in anchors else GREEN
            body = self._marker(t, "bodies", r, marker.CYLINDER, color)
            body.pose = self._pose(pose)
            body.scale.x = body.scale.y = 2 * self.radius
            body.scale.z = 0.05
            label = self._marker(t, "ids", r, marker.TEXT_VIEW_FACING, WHITE)
            label.pose.position.x, label.pose.position.y, label.pose.position.z = float(pose[0]), float(pose[1]), 0.15
            label.scale.z, label.text = 0.1, f"{r}{' anchor' if r in anchors else ''}"
            ring = self._marker(t, "covariance", r, marker.LINE_STRIP, color)
            ring.scale.x = 0.01
            ring.points = [self._point(pose[0] + x, pose[1] + y) for x, y in ellipse(c[:2, :2])]
            out.markers += [body, label, ring]
        if self.traj is not None and self._plan is not None and 1 <= self._plan.config <= len(self.traj.configurations):
            desired = self._marker(t, "desired", 0, marker.SPHERE_LIST, RED)
            desired.scale.x = desired.scale.y = desired.scale.z = 0.06
            desired.points = [self._point(x, y) for x, y in self.traj.configurations[self._plan.config - 1]]
            out.markers.append(desired)
        return out

    def _point(self, x: float, y: float) -> Any:
        p = self._m["Point"]()
        p.x, p.y = float(x), float(y)
        return p

    def _on_estop(self, request: Any, response: Any) -> Any:
        from coordinator.node.stop import emergency_stop  # noqa: PLC0415 - zenoh's stop path, only when called

        out = emergency_stop(self.settings, self.run_id, f"swarm ros2 bridge (pid {os.getpid()})", "/swarm/estop service", 0.3, 1.0)
        robots = ", ".join(map(str, out.agents))
        response.success = bool(out.agents or out.links)
        response.message = (f"emergency stop of run {self.run_id} acknowledged by {len(out.agents)} agents"
                            f"{f' (robots {robots})' if robots else ''} and {len(out.links)} links")
        _log.warning("bridge: %s", response.message)
        return response

    def close(self) -> None:
        for sub in self._subs:
            sub.undeclare()
        RosProcess.remove(self._node)
