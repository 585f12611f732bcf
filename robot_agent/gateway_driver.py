"""The gateway driver: a real (or emulated) robot reached through the link process of its port.

Same ``Driver`` interface as ``SimDriver``; the agent does not know which one it has.
``execute`` publishes a ``LinkRequest`` ``command`` (drive corrected by the robot's
``motion_scale``, the command's coordinator ``epoch``, and its ``start_pose`` for the record) on
``swarm/<run>/robot/<id>/linkreq`` and waits for the link's ``LinkReply`` ``done``;
``sense`` asks for ``observe`` and corrects the raw measurements (range bias, bearing
offset: ``runtime.gateway.config.Calibration``). A ``refused`` answer raises
``DriverRefused``; ``lost`` for the step being waited on (a ``lost`` for another step is
ignored and counted in ``ignored_replies``), the disappearance of the liveliness token of
the link process of ``port`` (``swarm/<run>/alive/link/<port>``), or no answer within
``Timing.answer_timeout_s`` raises ``RobotLost``. The token is watched all the time: while
idle, ``lost_reason`` says the link is gone and ``check`` raises ``RobotLost``, and the
``on_lost`` callback (if set) is called once from the Zenoh thread, so an idle agent reports
its robot lost at once too. ``estop`` may be called from any thread: the emergency stop
goes out at once and also ends a wait in progress (``DriverRefused``).
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING

import numpy as np

from robot_agent.driver import Driver, DriverRefused, PeerPoses, RobotLost
from runtime.gateway.config import Calibration, Timing
from runtime.wire.keys import link_alive_key, robot_key
from runtime.wire.messages import LinkReply, LinkRequest, MessageError, MotionCommand, decode, encode
from runtime.wire.transport import publish, subscribe, watch_liveliness

if TYPE_CHECKING:
    import zenoh

    from robot_agent.link import Link


class GatewayDriver(Driver):
    """Robot ``robot`` of run ``run`` behind a link process; ``attach(session)`` before use."""

    simulated = False

    def __init__(self, run: str, robot: int, calibration: Calibration = Calibration(), timing: Timing = Timing(),
                 port: str | None = None) -> None:
        self.run_id = run
        self.robot = int(robot)
        self.calibration = calibration
        self.timing = timing
        self._session: zenoh.Session | None = None
        self._sub: zenoh.Subscriber[None] | None = None
        self._replies: queue.SimpleQueue[LinkReply] = queue.SimpleQueue()  # C-level: cheaper per reply than queue.Queue
        self._estopped = threading.Event()
        self.port = port
        self._link_seen = threading.Event()  # the link's liveliness token appeared
        self._link_gone = threading.Event()  # ... and disappeared since
        self._watch: zenoh.Subscriber[None] | None = None
        self._req_key = robot_key(run, self.robot, "linkreq")
        self._rep_key = robot_key(run, self.robot, "linkrep")
        self.bad_replies = 0  # undecodable LinkReplies
        self.ignored_replies = 0  # `lost` replies for a step not waited on
        self.on_lost: Callable[[str], None] | None = None  # called once (Zenoh thread) when the link disappears
        self._submit: Callable[[LinkRequest], None] | None = None  # the link in this process (``use_link``)

    def use_link(self, link: Link) -> None:
        """Talk to ``link``, which runs in this process (``swarm agent --link``), directly; call before ``attach``.
        Requests go to it on the calling thread and its replies come back without a Zenoh hop; both are still
        published on the robot's keys, so a recording holds the same messages as with a link process."""
        self._submit = link.serve_locally(self.robot, self._replies.put)

    def attach(self, session: zenoh.Session) -> None:
        """Start talking to the link over ``session`` (the agent's)."""
        self._session = session
        if self._submit is None:
            self._sub = subscribe(session, self._rep_key, self._on_reply)
        if self.port is not None:
            self._watch = watch_liveliness(session, link_alive_key(self.run_id, self.port), self._on_link)

    def detach(self) -> None:
        for sub in (self._sub, self._watch):
            if sub is not None:
                sub.undeclare()
        self._sub = self._watch = None

    def ready(self, timeout_s: float) -> bool:
        """Whether the link process of the robot's port is up (its token seen), waiting up to ``timeout_s``.

        The link declares its token after its subscriptions, so a request sent from now on reaches it.
        Without a ``port`` there is nothing to wait for.
        """
        return self.port is None or self._link_seen.wait(timeout_s)

    def _on_link(self, key: str, alive: bool) -> None:  # Zenoh thread: flags and the callback only
        if alive:
            self._link_seen.set()
            self._link_gone.clear()
        elif self._link_seen.is_set() and not self._link_gone.is_set():
            self._link_gone.set()
            reason = self.lost_reason()
            if self.on_lost is not None and reason is not None:
                self.on_lost(reason)

    def lost_reason(self) -> str | None:
        """Why the robot cannot be reached any more (its link process is gone), or None."""
        return f"robot {self.robot}: the link process of port {self.port} is gone" if self._link_gone.is_set() else None

    def check(self) -> None:
        """Raise ``RobotLost`` if the link process of the robot's port is gone (idle or not)."""
        reason = self.lost_reason()
        if reason is not None:
            raise RobotLost(reason)

    def _on_reply(self, key: str, payload: bytes) -> None:  # Zenoh thread: decode and enqueue only
        try:
            self._replies.put(decode(payload, LinkReply, key=key))
        except MessageError:
            self.bad_replies += 1

    def _request(self, step: int, kind: str, turn_rad: float = 0.0, drive_m: float = 0.0, start_pose: tuple[float, ...] = (),
                 epoch: int = 0) -> None:
        msg = LinkRequest(run=self.run_id, step=step, robot=self.robot, kind=kind, turn_rad=turn_rad, drive_m=drive_m,
                          start_pose=start_pose, epoch=epoch)
        assert self._session is not None, "attach() first"
        publish(self._session, self._req_key, encode(msg))
        if self._submit is not None:
            self._submit(msg)

    def _exchange(self, step: int, final: str, motion: bool, kind: str, turn_rad: float = 0.0, drive_m: float = 0.0,
                  start_pose: tuple[float, ...] = (), epoch: int = 0) -> LinkReply:
        """Send the request, then wait for its reply of kind ``final``; raises on refusal, loss, stop or timeout.

        The request is sent again whenever the link has been silent about it for ``_resend_s``
        (a request published before the link subscribed, or a lost reply): the link ignores a
        copy of the request in flight, and the robot answers a repeated step from memory
        (docs/gateway-protocol.md), so nothing runs twice.
        """
        resend_s, timeout_s = self.timing.resend_s, self.timing.answer_timeout_s(motion)
        self._request(step, kind, turn_rad, drive_m, start_pose, epoch)
        start = time.monotonic()
        deadline, next_resend = start + timeout_s, start + resend_s
        while True:
            if self._estopped.is_set():
                raise DriverRefused("emergency stop")
            self.check()
            left = deadline - time.monotonic()
            if left <= 0:
                raise RobotLost(f"robot {self.robot}: no answer from the link within {timeout_s:.1f} s (is `swarm link` running?)")
            try:
                reply = self._replies.get(timeout=min(left, 0.05))
            except queue.Empty:
                if time.monotonic() >= next_resend:
                    self._request(step, kind, turn_rad, drive_m, start_pose, epoch)
                    next_resend = time.monotonic() + resend_s
                continue
            if reply.step != step:
                self.ignored_replies += reply.kind == "lost"  # a lost robot is reported for the step in flight
                continue  # a late answer to an earlier request, or a forged one
            if reply.kind == "lost":
                raise RobotLost(reply.reason)
            if reply.kind == "refused":
                raise DriverRefused(reply.reason)
            if reply.kind == final:
                return reply

    # -- Driver --------------------------------------------------------------------------------

    def execute(self, command: MotionCommand) -> None:
        if self._estopped.is_set():
            raise DriverRefused("emergency stop")
        self._exchange(command.step, "done", True, "command", command.turn_rad, self.calibration.corrected_drive(command.drive_m),
                       tuple(command.start_pose), command.epoch)
        return None

    def true_pose(self) -> None:
        return None

    def sense(self, peers: PeerPoses | Mapping[int, np.ndarray] | None, step: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        reply = self._exchange(step, "observation", False, "observe")
        c = self.calibration
        ranges = np.array([c.corrected_range(r) for r in reply.ranges], dtype=float)
        bearings = np.array([c.corrected_bearing(b) for b in reply.bearings], dtype=float)
        return np.array(reply.observed, dtype=np.int64), ranges, bearings

    def stop(self) -> None:
        """Nothing to send: the robot runs one bounded command at a time and is idle between them (the frame
        protocol has no unlatched stop; ``estop`` halts a motion in progress)."""

    def estop(self, step: int = 0) -> None:
        """Forward an emergency stop to the robot at once (any thread)."""
        self._estopped.set()
        if self._session is not None:
            self._request(step, "estop")
