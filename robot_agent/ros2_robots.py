"""Simulated robots that speak the ROS 2 driver's interface (``swarm ros2 robots``; docs/ros2.md).

``SimRobots`` runs one node per robot of a trajectory in its namespace (``Ros2Config``: namespace, frame,
topic names) on one world (``runtime.models.world``: ``step(dt, twists)``, ``poses``, ``odometry``,
``speeds``, ``sightings``). Each tick (``rate_hz``) it holds every robot's latest ``cmd_vel`` (zero once older than
``CMD_TIMEOUT_S``, as a real base stops when its commands stop), steps the world by the elapsed time,
calls ``after_step`` (the physical world's events: ``robot_agent.ros2_physics``) and publishes ``odom``
(the world's odometry and encoder speeds, frame ``robot<i>/odom``) and, when named, the ground truth
(frame ``world``); every ``1 / sensing_hz`` seconds each robot's sensor frame goes out on ``neighbors``,
one ``TransformStamped`` per robot seen (the observed robot's position in the observer's body frame).

Faults, for tests and rehearsals: ``no_odom`` robots never publish odometry; ``silent = {id: n}`` robot ``id``
stops publishing anything (and stops) when its n-th motion starts, its node still up; ``twice`` sends every
sighting twice; ``late_s`` sends every sighting again that much later with its original stamp.
"""

from __future__ import annotations

import heapq
import itertools
import logging
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from robot_agent.ros2_config import Ros2Config
from runtime.models.world import World
from runtime.wire.ros2 import RosProcess, qos, require_ros2, set_yaw, stamp

_log = logging.getLogger(__name__)
CMD_TIMEOUT_S = 0.5  # a robot whose last cmd_vel is older than this stops
WORLD_FRAME = "world"


class SimRobots:
    """The robots of ``world`` on ROS 2 (module doc); ``run()`` until ``stop()``."""

    def __init__(self, world: World, cfg: Ros2Config | None = None, *, rate_hz: float = 50.0, sensing_hz: float = 10.0,
                 ground_truth: str = "ground_truth", no_odom: frozenset[int] = frozenset(), silent: dict[int, int] | None = None,
                 twice: bool = False, late_s: float = 0.0, after_step: Callable[[], None] | None = None) -> None:
        require_ros2("swarm ros2 robots")
        from geometry_msgs.msg import TransformStamped, Twist  # noqa: PLC0415 - ROS 2 only here
        from nav_msgs.msg import Odometry  # noqa: PLC0415

        self.world, self.cfg = world, cfg or Ros2Config()
        self.ids = [int(i) for i in world.ids]
        self.dt, self.sensing_dt = 1.0 / rate_hz, 1.0 / sensing_hz
        self.no_odom, self.silent = no_odom, dict(silent or {})
        self.twice, self.late_s = twice, late_s
        self.after_step = after_step
        self._stop = threading.Event()
        n = len(self.ids)
        self._cmd = np.zeros((n, 2))
        self._cmd_at = np.zeros(n)  # monotonic time of each robot's latest cmd_vel
        self._moving = np.zeros(n, bool)
        self.motions = np.zeros(n, np.int64)  # motions started per robot
        self._muted = np.zeros(n, bool)
        self._twists = np.zeros((n, 2))  # of the latest tick
        self._late: list[tuple[float, int, Any, Any]] = []  # heap of (due, seq, publisher, message)
        self._seq = itertools.count()
        self._odometry, self._transform = Odometry, TransformStamped
        sensor = qos("best_effort", 50)
        self.nodes, self._odom_pubs, self._truth_pubs, self._seen_pubs = [], [], [], []
        try:
            for k, robot in enumerate(self.ids):
                node = RosProcess.add("sim_robot", self.cfg.namespace_of(robot))
                self.nodes.append(node)
                node.create_subscription(Twist, self.cfg.cmd_vel, lambda msg, k=k: self._on_cmd(k, msg), qos("best_effort", 10))
                self._odom_pubs.append(node.create_publisher(Odometry, self.cfg.odom, sensor))
                self._truth_pubs.append(node.create_publisher(Odometry, ground_truth, sensor) if ground_truth else None)
                self._seen_pubs.append(node.create_publisher(TransformStamped, self.cfg.neighbors, sensor))
        except BaseException:
            self.close()
            raise

    def _on_cmd(self, k: int, msg: Any) -> None:
        self._cmd[k] = (msg.linear.x, msg.angular.z)
        self._cmd_at[k] = time.monotonic()

    def stop(self) -> None:
        """End ``run`` (safe from a signal handler)."""
        self._stop.set()

    def close(self) -> None:
        for node in self.nodes:
            RosProcess.remove(node)
        self.nodes = []

    def run(self) -> None:
        """Step and publish until ``stop()``."""
        last = start = time.monotonic()
        next_sense = start
        for tick in itertools.count(1):
            if self._stop.wait(max(0.0, start + tick * self.dt - time.monotonic())):
                return
            now = time.monotonic()
            self._step(now - last, now)  # the elapsed time, late ticks included: world time is wall time
            last = now
            if self.after_step is not None:
                self.after_step()
            self._publish_state()
            if now >= next_sense:
                self._publish_sightings()
                next_sense += self.sensing_dt * max(1, int((now - next_sense) / self.sensing_dt) + 1)
            self._publish_late(now)

    def _step(self, dt: float, now: float) -> None:
        twists = np.where((now - self._cmd_at <= CMD_TIMEOUT_S)[:, None], self._cmd, 0.0)
        moving = np.any(twists != 0.0, axis=1)
        self.motions += moving & ~self._moving
        self._moving = moving
        for k, robot in enumerate(self.ids):
            if robot in self.silent and self.motions[k] >= self.silent[robot] and not self._muted[k]:
                self._muted[k] = True
                _log.warning("robot %d goes silent at its motion %d", robot, self.motions[k])
        twists[self._muted] = 0.0
        self.world.step(dt, twists)
        self._twists = self.world.speeds()

    def _publish_state(self) -> None:
        t = stamp()
        true, odom = self.world.poses(), self.world.odometry()
        for k, robot in enumerate(self.ids):
            if self._muted[k]:
                continue
            frame = self.cfg.frame_of(robot)
            if robot not in self.no_odom:
                self._odom_pubs[k].publish(self._odom_msg(t, f"{frame.rpartition('/')[0] or frame}/odom", frame, odom[k], self._twists[k]))
            pub = self._truth_pubs[k]
            if pub is not None:
                pub.publish(self._odom_msg(t, WORLD_FRAME, frame, true[k], self._twists[k]))

    def _odom_msg(self, t: Any, frame_id: str, child: str, pose: np.ndarray, twist: np.ndarray) -> Any:
        msg = self._odometry()
        msg.header.stamp, msg.header.frame_id, msg.child_frame_id = t, frame_id, child
        msg.pose.pose.position.x, msg.pose.pose.position.y = float(pose[0]), float(pose[1])
        set_yaw(msg.pose.pose.orientation, float(pose[2]))
        msg.twist.twist.linear.x, msg.twist.twist.angular.z = float(twist[0]), float(twist[1])
        return msg

    def _publish_sightings(self) -> None:
        t = stamp()
        due = time.monotonic() + self.late_s
        for k, robot in enumerate(self.ids):
            if self._muted[k]:
                continue
            seen, rho, phi = self.world.sightings(k)
            for other, r, b in zip(seen, rho, phi, strict=True):
                msg = self._transform()
                msg.header.stamp, msg.header.frame_id = t, self.cfg.frame_of(robot)
                msg.child_frame_id = self.cfg.frame_of(int(other))
                msg.transform.translation.x, msg.transform.translation.y = float(r * np.cos(b)), float(r * np.sin(b))
                msg.transform.rotation.w = 1.0
                pub = self._seen_pubs[k]
                pub.publish(msg)
                if self.twice:
                    pub.publish(msg)
                if self.late_s > 0:
                    heapq.heappush(self._late, (due, next(self._seq), pub, msg))

    def _publish_late(self, now: float) -> None:
        while self._late and self._late[0][0] <= now:
            _, _, pub, msg = heapq.heappop(self._late)
            pub.publish(msg)
