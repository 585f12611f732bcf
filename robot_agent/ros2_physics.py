"""The physical world of simulated ROS 2 robots on the run's record (``swarm ros2 robots --world physics --run RUN``).

``PhysicsRecorder`` joins the run's Zenoh network and, each time the world comes to rest after a motion
(``PhysicsWorld.take_quiet``), publishes what happened meanwhile as ``PhysicsEvent``s on
``swarm/<run>/sim/physics``, as the physics driver's world does (``robot_agent.physics_driver.physics_events``):
the contacts, the stalled drives and every true pose. ROS 2's ``cmd_vel`` carries no step number, so the
events carry the highest step of the run's ``MotionCommand``s heard so far (``swarm/<run>/robot/*/cmd``).
"""

from __future__ import annotations

import logging
import threading
from typing import TYPE_CHECKING

from robot_agent.physics_driver import physics_events
from runtime.wire.keys import robot_wildcard
from runtime.wire.messages import MessageError, MotionCommand, decode, encode, message_key
from runtime.wire.transport import publish, subscribe
from runtime.world.velocity import PhysicsWorld

if TYPE_CHECKING:
    import zenoh

_log = logging.getLogger(__name__)


class PhysicsRecorder:
    """``world``'s events of run ``run`` on ``session`` (module doc); ``poll()`` after every world step."""

    def __init__(self, session: zenoh.Session, run: str, world: PhysicsWorld) -> None:
        self.session, self.run, self.world = session, run, world
        self.step = 0  # the highest step commanded so far
        self.published = 0  # PhysicsEvent messages sent
        self._lock = threading.Lock()
        self._sub = subscribe(session, robot_wildcard(run, "cmd"), self._on_command)

    def _on_command(self, key: str, payload: bytes) -> None:
        try:
            step = decode(payload, MotionCommand, key=key).step
        except MessageError:
            return  # not ours to judge: the agent refuses it
        with self._lock:
            self.step = max(self.step, int(step))

    def poll(self) -> None:
        quiet = self.world.take_quiet()
        if quiet is None:
            return
        time_s, events, poses = quiet
        with self._lock:
            step = self.step
        ids = tuple(int(i) for i in self.world.ids)
        for msg in physics_events(self.run, step, time_s, events, ids, poses):
            try:
                publish(self.session, message_key(msg), encode(msg))
                self.published += 1
            except Exception:  # noqa: BLE001 - a closed session at shutdown must not stop the robots
                _log.warning("physics event of step %d not published", step, exc_info=True)
                return

    def close(self) -> None:
        self._sub.undeclare()
