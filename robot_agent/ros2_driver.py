"""``--driver ros2``: a robot that speaks standard ROS 2 interfaces (docs/ros2.md; settings: ``robot_agent.ros2_config``).

Per robot, in its namespace (default ``/robot<id>``), on one node per robot of this process's rclpy context:

* publishes ``cmd_vel`` (``geometry_msgs/Twist``): a command is executed as two velocity profiles within the
  limits, the turn (``angular.z``) then the drive (``linear.x``), at ``rate_hz``, then a zero twist: closed on
  the odometry when the robot publishes it (``closed_loop_speed``; the speeds sent after the odometry's stamp
  count as done), else open-loop (``velocity_profile``); the robot is at rest once its ``odom`` says so, or
  ``settle_s`` after the zero twist without odom.
  An emergency stop publishes a zero twist at once and refuses every later command (latched).
* subscribes ``odom`` (``nav_msgs/Odometry``, optional): motion completion and liveness;
  ``ground_truth`` (``nav_msgs/Odometry`` in the world frame, when configured: a tracker or simulator): the
  robot's true pose, which makes the driver ``simulated`` (the agent publishes truths, the run gets P_f);
  ``neighbors`` (``geometry_msgs/TransformStamped``, one per sighting; ``SightingWindow``): a ``sense`` call
  waits ``sensing_window_s`` and reports the newest sighting of each robot taken in that window.
  Subscriptions are best effort, so reliable and best-effort publishers both match.

Lost: nothing subscribes to ``cmd_vel`` any more, or the periodic topics heard so far (``odom``,
``ground_truth``) are silent for ``silence_s``: during a command or a sensing window ``RobotLost``, while
idle ``report_lost``. A namespace where no robot ever appears is not ready, and its first command is lost.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Mapping
from typing import Any

import numpy as np

from robot_agent.driver import Driver, DriverContext, DriverRefused, PeerPoses, RobotLost
from robot_agent.ros2_config import Ros2Config, SightingWindow, closed_loop_speed, velocity_profile
from runtime.wire.messages import MotionCommand
from runtime.wire.ros2 import RosProcess, qos, require_ros2, stamp_ns, yaw_of

_log = logging.getLogger(__name__)
AT_REST = 1e-3  # m/s and rad/s: odom twist below this is standing still
REST_WAIT_SILENCES = 5  # after a zero twist, messages stamped later must come within this many silence_s
WATCH_S = 0.1  # how often the idle watchdog looks
RECHECK_S = 0.05  # a silence is confirmed this much later


class Ros2Driver(Driver):
    """One robot behind ROS 2 topics (module doc); ``ctx.options``: ``config=FILE`` and settings (``Ros2Config.load``)."""

    def __init__(self, ctx: DriverContext) -> None:
        require_ros2("the ros2 driver")
        from geometry_msgs.msg import TransformStamped, Twist  # noqa: PLC0415 - ROS 2 only in this driver
        from nav_msgs.msg import Odometry  # noqa: PLC0415

        self.cfg = Ros2Config.load(dict(ctx.options))
        self.robot = int(ctx.robot)
        self.simulated = bool(self.cfg.ground_truth)
        self.namespace = self.cfg.namespace_of(self.robot)
        self._twist = Twist
        self._window = SightingWindow(self.robot, ctx.ids, self.cfg.frame)
        self._halt, self._closed = threading.Event(), threading.Event()
        self.estopped = False
        self._lock = threading.Lock()
        self._heard: dict[str, float] = {}  # periodic topic -> monotonic time last heard
        self._odom: tuple[int, float, float, np.ndarray] | None = None  # (stamp ns, |v|, |w|, pose) of the latest odom
        self._truth: tuple[int, np.ndarray] | None = None  # (stamp ns, pose) of the latest ground truth
        self._subscribed = 0.0  # monotonic time cmd_vel last had a subscriber (0: never)
        self._busy = False
        self._reported = False
        self._node = RosProcess.add(f"swarm_agent_{self.robot}", self.namespace)
        sensors = qos("best_effort", max(self.cfg.depth, 50))
        self._pub = self._node.create_publisher(Twist, self.cfg.cmd_vel, qos(self.cfg.cmd_vel_qos, self.cfg.depth))
        self._subs = [self._node.create_subscription(Odometry, self.cfg.odom, self._on_odom, sensors),
                      self._node.create_subscription(TransformStamped, self.cfg.neighbors, self._on_sighting, sensors)]
        if self.cfg.ground_truth:
            self._subs.append(self._node.create_subscription(Odometry, self.cfg.ground_truth, self._on_truth, sensors))
        self._watchdog = threading.Thread(target=self._watch, name=f"ros2-watch-{self.robot}", daemon=True)
        self._watchdog.start()

    # -- ROS 2 callbacks (executor threads) --------------------------------------------------

    def _on_odom(self, msg: Any) -> None:
        self._heard["odom"] = time.monotonic()
        tw, p = msg.twist.twist, msg.pose.pose
        self._odom = (stamp_ns(msg.header.stamp), abs(tw.linear.x), abs(tw.angular.z),
                      np.array([p.position.x, p.position.y, yaw_of(p.orientation)]))

    def _on_truth(self, msg: Any) -> None:
        self._heard["ground_truth"] = time.monotonic()
        p = msg.pose.pose
        self._truth = (stamp_ns(msg.header.stamp), np.array([p.position.x, p.position.y, yaw_of(p.orientation)]))

    def _on_sighting(self, msg: Any) -> None:
        t = msg.transform.translation
        self._window.add(stamp_ns(msg.header.stamp), msg.header.frame_id, msg.child_frame_id, t.x, t.y)

    # -- liveness -------------------------------------------------------------------------

    def _where(self, topic: str) -> str:
        return f"{self.namespace.rstrip('/')}/{topic}"

    def lost_reason(self) -> str | None:
        """Why the robot counts as lost now (module doc), or None."""
        now = time.monotonic()
        if self._pub.get_subscription_count() > 0:
            self._subscribed = now
        elif self._subscribed and now - self._subscribed > self.cfg.silence_s:
            return f"nothing subscribes to {self._where(self.cfg.cmd_vel)} any more"
        heard = dict(self._heard)
        if heard and now - max(heard.values()) > self.cfg.silence_s:
            time.sleep(RECHECK_S)  # this process may have been the one starved: let its executor take what is queued
            if time.monotonic() - max(self._heard.values()) > self.cfg.silence_s + RECHECK_S:
                topics = " and ".join(self._where(t) for t in sorted(heard))
                return f"robot {self.robot} went silent: nothing on {topics} for {time.monotonic() - max(self._heard.values()):.1f} s"
        return None

    def _check(self) -> None:
        reason = self.lost_reason()
        if reason is not None:
            raise RobotLost(reason)

    def _watch(self) -> None:
        while not self._closed.wait(WATCH_S):
            if self._busy or self._reported:
                continue
            reason = self.lost_reason()
            if reason is not None:
                self._reported = True
                self.report_lost(reason)

    def ready(self, timeout_s: float) -> bool:
        """A robot subscribes to ``cmd_vel`` (and its ground truth, if configured, has come)."""
        deadline = time.monotonic() + timeout_s
        while True:
            if self._pub.get_subscription_count() > 0 and (not self.cfg.ground_truth or self._truth is not None):
                self._subscribed = time.monotonic()
                return True
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.02)

    # -- commands -------------------------------------------------------------------------

    def _publish(self, v: float, w: float) -> None:
        msg = self._twist()
        msg.linear.x, msg.angular.z = float(v), float(w)
        with self._lock:
            self._pub.publish(msg)

    def execute(self, command: MotionCommand) -> np.ndarray | None:
        if self.estopped:
            raise DriverRefused("emergency stop")
        if self._pub.get_subscription_count() == 0:
            raise RobotLost(f"no robot on {self.namespace}: nothing subscribes to {self._where(self.cfg.cmd_vel)}")
        self._halt.clear()
        self._busy = True
        try:
            dt = 1.0 / self.cfg.rate_hz
            c = self.cfg
            if self._odom_fresh():  # closed on the odometry: exact in odometry terms, whatever the delays
                self._close(command.turn_rad, c.max_angular_speed, c.angular_accel, dt, angular=True)
                self._close(command.drive_m, c.max_linear_speed, c.linear_accel, dt, angular=False)
            else:
                self._follow(velocity_profile(command.turn_rad, c.max_angular_speed, c.angular_accel, dt), dt, angular=True)
                self._follow(velocity_profile(command.drive_m, c.max_linear_speed, c.linear_accel, dt), dt, angular=False)
            self._publish(0.0, 0.0)
            if not self._halt.is_set():
                self._settle(time.time_ns())
            if self._halt.is_set():
                raise DriverRefused("emergency stop" if self.estopped else "stopped during the motion")
        finally:
            self._busy = False
        return self.true_pose()

    def _odom_fresh(self) -> bool:
        heard = self._heard.get("odom")
        return self._odom is not None and heard is not None and time.monotonic() - heard < self.cfg.silence_s

    def _close(self, target: float, vmax: float, amax: float, dt: float, *, angular: bool) -> None:
        """Turn by ``target`` rad or drive ``target`` m, measured on the odometry (``closed_loop_speed`` each ``dt``). What
        the odometry cannot show yet, the speeds sent after its stamp, counts as done: delays do not make it overshoot."""
        if target == 0.0 or self._odom is None:
            return
        start = self._odom[3]
        done, last_yaw = 0.0, start[2]
        sent: list[tuple[int, float]] = []  # (time ns, speed) of every twist of this motion
        began = time.monotonic()
        limit = 3.0 * len(velocity_profile(target, vmax, amax, dt)) * dt + 2.0 * self.cfg.silence_s
        while not self._halt.is_set():
            self._check()
            odom_ns, *_, pose = self._odom
            if angular:
                done += math.remainder(pose[2] - last_yaw, 2 * math.pi)
                last_yaw = pose[2]
            else:
                done = math.hypot(pose[0] - start[0], pose[1] - start[1])
            pending = _unseen(sent, odom_ns, time.time_ns())
            elapsed = time.monotonic() - began
            progress = math.copysign(1.0, target) * done if angular else done
            speed = closed_loop_speed(abs(target) - progress - pending, elapsed, vmax, amax, dt)
            if speed == 0.0:
                return
            if elapsed > limit:
                raise RobotLost(f"robot {self.robot} did not complete its {'turn' if angular else 'drive'} of {target:.4g} "
                                f"{'rad' if angular else 'm'} in {elapsed:.1f} s: its odometry shows {done:.4g}")
            v = math.copysign(speed, target)
            sent.append((time.time_ns(), v))
            if angular:
                self._publish(0.0, v)
            else:
                self._publish(v, 0.0)
            self._halt.wait(dt)

    def _follow(self, speeds: np.ndarray, dt: float, *, angular: bool) -> None:
        """Publish ``speeds`` one per ``dt`` (absolute schedule), checking the robot is still there."""
        start = time.monotonic()
        for k, v in enumerate(speeds):
            if self._halt.is_set():
                return
            self._check()
            if angular:
                self._publish(0.0, v)
            else:
                self._publish(v, 0.0)
            if self._halt.wait(max(0.0, start + (k + 1) * dt - time.monotonic())):
                return

    def _settle(self, zero_ns: int) -> None:
        """Until the robot stands still after the zero twist at ``zero_ns``: its odom (when heard) says so in a
        message stamped ``settle_s`` later, and its ground truth (when configured) is as recent."""
        after = zero_ns + int(self.cfg.settle_s * 1e9)
        moving_since: float | None = None  # odometry stamped after the zero twist that still shows motion
        deadline = time.monotonic() + self.cfg.settle_s + REST_WAIT_SILENCES * self.cfg.silence_s
        while not self._halt.is_set():
            odom, truth = self._odom, self._truth
            fresh = odom is not None and odom[0] >= after
            at_rest = fresh and odom is not None and odom[1] < AT_REST and odom[2] < AT_REST
            odom_ok = "odom" not in self._heard or at_rest
            truth_ok = not self.cfg.ground_truth or (truth is not None and truth[0] >= after)
            if odom_ok and truth_ok and time.time_ns() >= after:
                return
            self._check()
            now = time.monotonic()
            moving_since = (moving_since or now) if fresh and not at_rest else None
            if moving_since is not None and now - moving_since > self.cfg.silence_s:
                raise RobotLost(f"robot {self.robot} keeps moving after the zero twist on {self._where(self.cfg.cmd_vel)} "
                                f"(its odometry, {now - moving_since:.1f} s)")
            if now > deadline:
                what = "odometry" if not odom_ok else "ground truth"
                raise RobotLost(f"robot {self.robot}: no {what} stamped after its zero twist within {now - deadline + self.cfg.settle_s:.1f} s "
                                f"(its clock behind the agent's, or its messages that late)")
            self._halt.wait(0.01)
        self._publish(0.0, 0.0)

    def sense(self, peers: PeerPoses | Mapping[int, np.ndarray] | None, step: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The newest sighting of each robot taken during the ``sensing_window_s`` that opens now (peers unused)."""
        since = time.time_ns()
        self._busy = True
        try:
            end = time.monotonic() + self.cfg.sensing_window_s
            while (left := end - time.monotonic()) > 0:
                self._check()
                self._closed.wait(min(left, 0.05))
            self._check()
        finally:
            self._busy = False
        if self._window.dropped:
            _log.debug("robot %d: sightings dropped %s", self.robot, self._window.dropped)
        return self._window.observations(since)

    def estop(self, step: int = 0) -> None:
        self.estopped = True
        self._halt.set()
        self._publish(0.0, 0.0)

    def stop(self) -> None:
        self._halt.set()
        try:
            self._publish(0.0, 0.0)
        except Exception:  # noqa: BLE001 - the context may be gone at exit: nothing left to stop
            _log.debug("robot %d: zero twist at stop not sent", self.robot)

    def true_pose(self) -> np.ndarray | None:
        truth = self._truth
        return None if truth is None else truth[1].copy()

    def detach(self) -> None:
        self._closed.set()
        self._watchdog.join(timeout=2 * WATCH_S + 1.0)
        RosProcess.remove(self._node)


def _unseen(sent: list[tuple[int, float]], since_ns: int, now_ns: int) -> float:
    """How far the speeds ``sent`` (time ns, speed; each held until the next, the last until ``now_ns``) took the robot
    after ``since_ns``: what odometry stamped then cannot show yet (m or rad)."""
    ends = [t for t, _ in sent[1:]] + [now_ns] if sent else []
    return sum(abs(v) * max(end - max(t, since_ns), 0) for (t, v), end in zip(sent, ends, strict=True)) / 1e9

