"""Simulated robots in the physical world (``swarm agent --world physics``, docs/physics.md).

One agent process hosts every robot of the run (the world is one), each agent with a
``PhysicsDriver`` on the process's ``SharedWorld``: a ``RealtimeWorld`` stepped by its own thread.
A command starts the robot's wheel-speed profiles at once and returns when the world is still,
with the robot's true pose; sensing reads the world (occlusion, field of view), not the peers'
truths the agent passes. The first agent to attach its Zenoh session gives the world a publisher:
after each step the world's contacts, stalls and true poses go out as ``PhysicsEvent``s on
``swarm/<run>/sim/physics``, so the recording holds them.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Mapping
from typing import TYPE_CHECKING

import numpy as np

from robot_agent.driver import Driver, DriverRefused, PeerPoses
from runtime.wire.messages import MotionCommand, PhysicsEvent, encode, message_key
from runtime.world.physics import Contact, Stuck, World, WorldEvent
from runtime.world.realtime import RealtimeWorld

if TYPE_CHECKING:
    import zenoh

_log = logging.getLogger(__name__)


def physics_events(run: str, step: int, time_s: float, events: list[WorldEvent], ids: tuple[int, ...],
                   poses: np.ndarray) -> list[PhysicsEvent]:
    """The ``PhysicsEvent`` messages of one quiet moment (world time ``time_s``): its contacts and stalls, then every true pose."""
    row = {r: k for k, r in enumerate(ids)}
    out = []
    for e in events:
        if isinstance(e, Contact):
            end = e.end_s
            out.append(PhysicsEvent(run=run, step=step, kind="contact", time_s=e.start_s, robots=(e.a, e.b),
                                    poses=(tuple(poses[row[e.a]]), tuple(poses[row[e.b]])), point=e.point,
                                    duration_s=max(0.0, (end if end is not None else time_s) - e.start_s),
                                    ongoing=int(end is None), impulse_n_s=e.impulse_n_s))
        elif isinstance(e, Stuck):
            out.append(PhysicsEvent(run=run, step=step, kind="stuck", time_s=e.time_s, robots=(e.robot,), poses=(e.pose,),
                                    commanded_m=max(0.0, e.commanded_m), achieved_m=e.achieved_m))
    out.append(PhysicsEvent(run=run, step=step, kind="poses", time_s=time_s, robots=ids, poses=tuple(map(tuple, poses))))
    return out


class SharedWorld:
    """The physical world of one process's agents: ``RealtimeWorld`` of ``world``, started at once, closed when the
    last driver detaches; publishes ``PhysicsEvent``s of run ``run`` on the first session attached."""

    def __init__(self, world: World, run: str, speed: float = 0.0) -> None:
        self.run = run
        self.realtime = RealtimeWorld(world, speed, on_quiet=self._publish)
        self._session: zenoh.Session | None = None
        self._users = 0
        self._lock = threading.Lock()
        self.realtime.start()

    def attach(self, session: zenoh.Session) -> None:
        with self._lock:
            self._users += 1
            if self._session is None:
                self._session = session

    def detach(self) -> None:
        with self._lock:
            self._users -= 1
            last = self._users <= 0
            if last:
                self._session = None
        if last:
            self.realtime.close()

    def _publish(self, step: int, time_s: float, events: list[WorldEvent], ids: tuple[int, ...], poses: np.ndarray) -> None:
        from runtime.wire.transport import publish  # noqa: PLC0415 - zenoh only in processes that publish

        with self._lock:
            session = self._session
        if session is None:
            return
        for msg in physics_events(self.run, step, time_s, events, ids, poses):
            try:
                publish(session, message_key(msg), encode(msg))
            except Exception:  # noqa: BLE001 - a closed session at shutdown must not stop the world
                _log.warning("physics event of step %d not published", step, exc_info=True)
                return


class PhysicsDriver(Driver):
    """Robot ``robot`` of ``shared``'s world."""

    simulated = True  # the agent publishes its truth and waits for the step's truth set before sensing (as for SimDriver)

    def __init__(self, robot: int, shared: SharedWorld) -> None:
        self.robot = int(robot)
        self.shared = shared
        shared.realtime.world.index(robot)  # an unknown robot is refused now
        self.estopped = False

    def attach(self, session: zenoh.Session) -> None:
        self.shared.attach(session)

    def detach(self) -> None:
        self.shared.detach()

    def execute(self, command: MotionCommand) -> np.ndarray:
        if self.estopped:
            raise DriverRefused("emergency stop")
        pose = self.shared.realtime.execute(self.robot, command.turn_rad, command.drive_m, command.step)
        if self.estopped:
            raise DriverRefused("emergency stop during the motion")
        return pose

    def sense(self, peers: PeerPoses | Mapping[int, np.ndarray] | None, step: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The world's sightings of this robot (``peers`` is not needed: the world holds every body)."""
        return self.shared.realtime.sense(self.robot)

    def estop(self, step: int = 0) -> None:
        self.estopped = True
        self.shared.realtime.halt(self.robot)

    def stop(self) -> None:
        self.shared.realtime.halt(self.robot)

    def true_pose(self) -> np.ndarray:
        return self.shared.realtime.pose(self.robot)
