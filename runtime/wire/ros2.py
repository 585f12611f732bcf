"""ROS 2 plumbing shared by the ROS 2 driver, the simulated ROS 2 robots and the live bridge (extra ``ros2``).

rclpy and the message packages are imported only through ``require_ros2``: without them it raises a
``SwarmInputError`` naming the extra, so a command says in one line what to install. A process has one
rclpy context (``RosProcess``): nodes join it and leave it, one executor spins them on a daemon thread,
and the context ends with the last node. rclpy's own signal handlers are not installed (the commands
handle SIGINT/SIGTERM themselves). Which middleware and domain: the usual variables, ``ROS_DOMAIN_ID``,
``ROS_AUTOMATIC_DISCOVERY_RANGE`` and ``RMW_IMPLEMENTATION`` (docs/ros2.md).
"""

from __future__ import annotations

import math
import threading
import time
from typing import Any

from runtime.errors import SwarmInputError

EXTRA = "pip install 'inchworm-swarm[ros2]'"
RELIABILITIES = ("reliable", "best_effort")


def require_ros2(what: str) -> None:
    """Raise ``SwarmInputError`` naming the extra unless rclpy and the message packages import."""
    try:
        import geometry_msgs.msg  # noqa: F401, PLC0415 - ROS 2 only where it is used
        import nav_msgs.msg  # noqa: F401, PLC0415
        import rclpy  # noqa: F401, PLC0415
        import std_srvs.srv  # noqa: F401, PLC0415
        import visualization_msgs.msg  # noqa: F401, PLC0415
    except ImportError as exc:
        raise SwarmInputError(f"{what} needs ROS 2 (rclpy and the message packages; missing {exc.name}): {EXTRA}") from None


def qos(reliability: str, depth: int = 10, latched: bool = False) -> Any:
    """A QoS profile: ``reliable`` or ``best_effort`` (a best-effort subscriber accepts both kinds of publisher);
    ``latched``: transient local, so a subscriber that joins late gets the last ``depth`` messages."""
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy  # noqa: PLC0415

    if reliability not in RELIABILITIES:
        raise SwarmInputError(f"QoS reliability must be one of {', '.join(RELIABILITIES)}, got {reliability!r}")
    return QoSProfile(depth=int(depth), reliability=ReliabilityPolicy.RELIABLE if reliability == "reliable" else ReliabilityPolicy.BEST_EFFORT,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE)


def stamp(ns: int | None = None) -> Any:
    """A ``builtin_interfaces/Time`` of ``ns`` (default now, system clock)."""
    from builtin_interfaces.msg import Time  # noqa: PLC0415

    ns = time.time_ns() if ns is None else int(ns)
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def stamp_ns(t: Any) -> int:
    """Nanoseconds of a ``builtin_interfaces/Time``."""
    return int(t.sec) * 1_000_000_000 + int(t.nanosec)


def yaw_of(q: Any) -> float:
    """The heading (rad) of a quaternion (rotation about z)."""
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def set_yaw(q: Any, yaw: float) -> None:
    """Write the rotation by ``yaw`` about z into quaternion ``q``."""
    q.x, q.y, q.z, q.w = 0.0, 0.0, math.sin(yaw / 2.0), math.cos(yaw / 2.0)


class RosProcess:
    """This process's rclpy context and executor; ``add(name, namespace)`` a node, ``remove(node)`` it."""

    _lock = threading.Lock()
    _nodes: list[Any] = []
    _context: Any = None
    _executor: Any = None
    _thread: threading.Thread | None = None

    @classmethod
    def add(cls, name: str, namespace: str = "") -> Any:
        import rclpy  # noqa: PLC0415
        from rclpy.context import Context  # noqa: PLC0415
        from rclpy.executors import MultiThreadedExecutor  # noqa: PLC0415
        from rclpy.signals import SignalHandlerOptions  # noqa: PLC0415

        with cls._lock:
            if cls._context is None:
                cls._context = Context()
                rclpy.init(context=cls._context, signal_handler_options=SignalHandlerOptions.NO)
                cls._executor = MultiThreadedExecutor(num_threads=2, context=cls._context)
                cls._thread = threading.Thread(target=cls._spin, args=(cls._executor,), name="ros2-executor", daemon=True)
                cls._thread.start()
            try:
                node = rclpy.create_node(name, namespace=namespace, context=cls._context)
            except Exception as exc:  # noqa: BLE001 - rclpy's invalid name/namespace errors: one line naming it
                if not cls._nodes:
                    cls._shutdown()
                raise SwarmInputError(f"ROS 2 node {name!r} in namespace {namespace!r}: {exc}") from None
            cls._nodes.append(node)
            cls._executor.add_node(node)
            return node

    @staticmethod
    def _spin(executor: Any) -> None:
        try:
            executor.spin()
        except Exception:  # noqa: BLE001 - the context was shut down under it: the process is leaving
            pass

    @classmethod
    def remove(cls, node: Any) -> None:
        with cls._lock:
            if node not in cls._nodes:
                return
            cls._nodes.remove(node)
            cls._executor.remove_node(node)
            node.destroy_node()
            if not cls._nodes:
                cls._shutdown()

    @classmethod
    def _shutdown(cls) -> None:
        executor, context, thread = cls._executor, cls._context, cls._thread
        cls._executor = cls._context = cls._thread = None
        if executor is not None:
            executor.shutdown(timeout_sec=1.0)
        if context is not None and context.ok():
            context.try_shutdown()
        if thread is not None:
            thread.join(timeout=2.0)
