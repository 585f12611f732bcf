"""The link process of one serial/radio port: the only owner of the device, shared by the agents over Zenoh.

Agents of the robots behind the port (gateway driver) publish ``LinkRequest``s on
``swarm/<run>/robot/<id>/linkreq``; the link turns each into a frame
(docs/gateway-protocol.md), sends it with retransmission (same SEQ, at most
``ack_timeout_s`` apart, also after ACCEPTED until DONE: the robot answers a repeated
COMMAND from memory, so a lost DONE costs one interval), and publishes the robot's answers
as ``LinkReply``s on ``.../linkrep`` (not ACCEPTED, which only shows the robot is alive: the
agent waits for DONE). Every answer restarts the count of ``max_retries``; a robot silent
through all of them (``Timing.retry_budget_s``), silent for ``robot_timeout_s``, or still
moving after ``motion_timeout_s`` is reported ``lost``. It sends a HEARTBEAT to every
robot that got no other frame for ``heartbeat_period_s``. The link trusts no request: a
motion goes to a robot only as the live coordinator commanded it (its own ``MotionCommand``
on ``robot/<id>/cmd``, of the live run's epochs, same step, turn and calibrated drive, the
robot's next step; ``_authority``), with no coordinator alive only stops go out, and one
that does not fit the frame's wire types (u32 step, float32 turn and drive) or breaks the
gateway config's limits or workspace is dropped and counted (``LinkStats.rejected``), never
sent. When the coordinator's liveliness token appears, a new run begins: the link forgets
what it had in flight, gives lost robots another chance and sends every robot RUN with a
fresh epoch (it forgets its step memory); requests wait until the robot answered RUN_ACK. An
``EmergencyStop`` on ``swarm/<run>/estop`` naming robots (the coordinator's stop of a lost
robot) is sent as ESTOP to those robots of the port only; one naming none is sent at once as a broadcast ESTOP and then to
each robot until it answers ESTOPPED; either is acknowledged with an ``EstopAck`` naming the port and the
robots it stopped. ``LinkStats`` go out every ``stats_period_s``, when
the coordinator's liveliness token appears or disappears (so a recording of the run holds
the link's counters at its start and end) and when the link stops. While it runs it holds
the liveliness token ``swarm/<run>/alive/link/<port>``: an agent whose link disappears
reports its robot lost at once instead of waiting for a timeout.

Threads, sharing the state under one lock: the reader (device -> frames, ``FrameDecoder``
with ``resync`` on a quiet line) handles the robots' answers itself and publishes the
replies; the engine (``run``) handles the agents' requests, emergency stops and timers
(heartbeats, retransmissions, losses, stats). Zenoh callbacks only enqueue for the engine.
In a port process (``swarm agent --link``, ``robot_agent.host``) the agents of the port's
robots run beside the link: their requests are handled on their own threads (``submit``)
and the replies handed to them directly (``serve_locally``); both are still published.
The frames of one turn of the engine, of the reader or of a ``submit`` go out in one write.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import os
import queue
import secrets
import select
import statistics
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

from robot_agent.write_batch import WriteBatch
from runtime.errors import SwarmConnectionError
from runtime.gateway.config import Calibration, GatewayConfig, Limits, Port, Timing
from runtime.gateway.frames import (
    BROADCAST,
    MAX_U32,
    QUIET_S,
    Body,
    EmptyBody,
    ErrorBody,
    Frame,
    FrameDecoder,
    FrameError,
    FrameType,
    HeartbeatBody,
    MotionBody,
    ObservationBody,
    RefusalBody,
    RefusalCode,
    RunBody,
    StepBody,
    encode_frame,
    fits_f32,
)
from runtime.wire.keys import (
    KeyspaceError,
    alive_wildcard,
    coord_alive_key,
    coord_key,
    estop_key,
    link_alive_key,
    parse_coord_token,
    parse_key,
    robot_key,
)
from runtime.wire.messages import (
    CommandLimits,
    DropCounter,
    EmergencyStop,
    EstimateMessage,
    EstopAck,
    LinkReply,
    LinkRequest,
    LinkStats,
    MotionCommand,
    ObserveRequest,
    decode_or_drop,
    encode,
    message_key,
)
from runtime.wire.transport import declare_token, publish, subscribe, watch_liveliness

if TYPE_CHECKING:
    import zenoh

_log = logging.getLogger(__name__)
RTT_WINDOW = 1000
STALL_S = 0.5  # s between two turns of the engine beyond which the link itself was stalled (it turns every ack_timeout_s / 2)
MAX_STEP_AHEAD = 1000  # a request more steps than this ahead of the robot's latest is refused (a step jump would strand the run)
MAX_HELD = 4  # commands per robot held until their coordinator's MotionCommand arrives (the oldest is dropped beyond)
_HOLD = "hold"  # ``_authority``: not proven yet, the coordinator's command may still be on its way


class ByteLink(Protocol):
    """A byte pipe to the robots: a serial port, a pty, an ANT channel."""

    def read(self, timeout_s: float) -> bytes:
        """Bytes available within ``timeout_s`` (b"" if none)."""
        ...

    def write(self, data: bytes) -> None: ...

    def close(self) -> None: ...


class SerialLink:
    """A serial device (or the pty of an emulator): pyserial opens and configures it (baud, 8N1, raw);
    reads and writes then go straight to its file descriptor (pyserial's own calls cost a
    select and, for read timeouts, a port reconfiguration each)."""

    def __init__(self, device: str, baud: int) -> None:
        import serial  # noqa: PLC0415 - keeps pyserial off the import path of processes that never open a port

        try:
            self._serial = serial.Serial(device, baudrate=baud, timeout=0)
        except (serial.SerialException, OSError) as exc:
            raise SwarmConnectionError(f"cannot open serial device {device}: {exc}") from None
        self._fd = self._serial.fileno()
        self._lock = threading.Lock()

    def read(self, timeout_s: float) -> bytes:
        ready, _, _ = select.select([self._fd], [], [], timeout_s)
        if not ready:
            return b""
        data = os.read(self._fd, 4096)
        if not data:
            raise SwarmConnectionError(f"serial device {self._serial.port} closed")
        return data

    def write(self, data: bytes) -> None:
        view = memoryview(data)
        with self._lock:
            while view:
                try:
                    view = view[os.write(self._fd, view):]
                except BlockingIOError:
                    select.select([], [self._fd], [], 0.1)

    def close(self) -> None:
        self._serial.close()


def open_link(port: Port) -> ByteLink:
    """The ``ByteLink`` of a configured port (``transport`` serial, or ant through openant)."""
    if port.transport == "ant":
        from robot_agent.ant_link import AntLink  # noqa: PLC0415 - optional extra

        return AntLink(port.device)
    return SerialLink(port.device, port.baud)


@dataclass
class _Request:
    """A request in flight to one robot."""

    kind: str  # command, observe, estop, reset, run
    step: int
    seq: int
    wire: bytes
    sent_at: float
    first_sent_at: float
    retries: int = 0  # retransmissions since the robot last answered
    accepted_at: float | None = None  # first ACCEPTED (a COMMAND being executed)
    answered: bool = False
    motion: tuple[float, float] = (0.0, 0.0)  # a COMMAND's turn (rad) and the distance the robot really drives (m)
    parts: dict[int, ObservationBody] = field(default_factory=dict)

    def due(self, timing: Timing) -> float:
        """When to retransmit: ``ack_timeout_s`` after the last transmission, whatever the robot answered so far."""
        return self.sent_at + timing.ack_timeout_s


@dataclass
class _Robot:
    id: int
    seq: int = 0
    last_rx: float = 0.0
    last_tx: float = -math.inf
    lost: bool = False
    busy: _Request | None = None  # command or observe
    control: _Request | None = None  # estop or reset
    begin: _Request | None = None  # RUN of a new run: requests wait for its RUN_ACK
    waiting: deque[LinkRequest] = field(default_factory=deque)  # LinkRequests behind ``busy`` or ``begin``
    latest: int = 0  # the latest step of a request sent this run
    ordered: MotionCommand | None = None  # the coordinator's latest MotionCommand for this robot (its own key, its identity)
    asked: ObserveRequest | None = None  # ... and its latest ObserveRequest
    commanded: int = 0  # the step of the latest COMMAND sent this run ...
    executed: bool = False  # ... and whether the robot reported it DONE (only then is it sent again: answered from memory)
    held: list[tuple[LinkRequest, float]] = field(default_factory=list)  # commands awaiting their coordinator's: (request, until)
    unanswered_since: float | None = None  # the first frame written to it since its last answer
    reckoned: tuple[float, float, float] | None = None  # its pose: the coordinator's estimate, moved by every DONE since
    agent_seen: bool = False  # its agent's liveliness token appeared ...
    agent_gone: bool = False  # ... and disappeared since: the link stops feeding the robot

    def requests(self) -> tuple[_Request, ...]:
        return tuple(r for r in (self.busy, self.control, self.begin) if r is not None)

    def next_seq(self) -> int:
        self.seq = self.seq % 0xFFFF + 1  # 1..65535, 0 never used by the gateway
        return self.seq


@dataclass
class LinkCounters:
    frames_sent: int = 0
    retransmissions: int = 0
    timeouts: int = 0
    rejected: int = 0
    unauthorised: int = 0  # of ``rejected``: requests no live coordinator commanded (forged, stale, future, none alive)
    epoch: int = 0  # the run epoch last begun (0: none yet)
    rtts_ms: deque[float] = field(default_factory=lambda: deque(maxlen=RTT_WINDOW))


class Link:
    """The link engine of ``port`` for run ``run`` over ``device``, talking Zenoh on ``session``.

    ``limits`` and ``calibration`` (the gateway config's) bound what a command may make a
    robot do: the distance it really drives (wire drive x ``motion_scale``) and its turn.
    """

    def __init__(self, session: zenoh.Session, run: str, port: Port, timing: Timing, device: ByteLink, limits: Limits = Limits(),
                 calibration: dict[int, Calibration] | None = None) -> None:
        self.session = session
        self.run_id = run
        self.port = port
        self.timing = timing
        self.limits = CommandLimits(max_drive_m=limits.max_drive_m, max_turn_rad=limits.max_turn_rad, workspace=limits.workspace)
        self.calibration = dict(calibration or {})
        self.device = device
        self.decoder = FrameDecoder()
        self._writes = WriteBatch(device.write)  # the frames of one turn of the engine or the reader go out in one write
        self.counters = LinkCounters()
        self.drops = DropCounter(_log)
        self.robots = {r: _Robot(r) for r in port.robots}
        self._events: queue.SimpleQueue[tuple[Any, ...]] = queue.SimpleQueue()  # C-level: the cheapest hand-over from Zenoh threads
        self._lock = threading.RLock()  # robots, counters, device writes: reader and engine
        self._stop = threading.Event()
        self._heartbeats: dict[tuple[int, int], float] = {}  # (robot, seq) -> sent
        self._broadcast_seq = 0
        self._subs: list[zenoh.Subscriber[None]] = []
        self._coord_seen = False  # the coordinator's token appeared ...
        self._coord_gone = False  # ... and disappeared since (or the session to it was lost): the link stops feeding
        self._coord_epochs: set[int] = set()  # the coordinator epochs of the current run (taken over from one another)
        self._coord_live: set[int] = set()  # those whose token is alive
        self._estimate_key = coord_key(run, "estimate")
        self._cmd_keys = {robot_key(run, r, "cmd"): r for r in port.robots}  # the coordinator's own commands (its identity only)
        self._observe_keys = {robot_key(run, r, "observe"): r for r in port.robots}  # ... and observation requests
        self._local: dict[int, Callable[[LinkReply], object]] = {}  # robots whose agents run in this process -> their reply sink

    @classmethod
    def open(cls, session: zenoh.Session, run: str, port: Port, config: GatewayConfig) -> Link:
        """The link of ``port`` with the gateway ``config``'s timing, limits and calibration, its device opened
        (``ConnectionError`` if it cannot be); ``close()`` it after ``run``."""
        device = open_link(port)
        return cls(session, run, port, config.timing, device, config.limits, {r: config.calibration_of(r) for r in port.robots})

    # -- lifecycle ------------------------------------------------------------------------

    def stop(self) -> None:
        self._stop.set()

    def close(self) -> None:
        """Close the device (after ``run`` returned)."""
        self.device.close()

    def serve_locally(self, robot: int, on_reply: Callable[[LinkReply], object]) -> Callable[[LinkRequest], None]:
        """Serve the agent of ``robot`` running in this process (``AgentHost`` with ``--link``); call before ``run``.

        Its requests come through the function returned, handled on the caller's thread (no Zenoh thread, no engine
        turn in between); its replies go to ``on_reply`` (from the reader's or the engine's thread). Both still go out
        on Zenoh for the record (a recorder gets them), but the link does not subscribe to that robot's requests."""
        if robot not in self.robots:
            raise ValueError(f"robot {robot} is not behind port {self.port.name}")
        self._local[robot] = on_reply
        return self.submit

    def submit(self, req: LinkRequest) -> None:
        """A request of a robot served locally (``serve_locally``), handled now, on this thread."""
        with self._lock, self._writes.collect():
            self._handle_safely(("local", req))

    def summary(self) -> str:
        """One line of the port's counters, for the end of a run."""
        s = self.stats()
        return (f"port {self.port.name}: {s.frames_sent} frames sent, {s.frames_received} received, {s.retransmissions} retransmissions, "
                f"{s.crc_errors} CRC errors, {s.rejected} requests rejected ({s.unauthorised} unauthorised), "
                f"round trip median {s.rtt_ms_median:.2f} ms")

    def run(self) -> int:
        """Serve until ``stop()``; publishes final stats; returns 0."""
        enqueue = lambda key, payload: self._events.put(("zenoh", key, payload))  # noqa: E731 (Zenoh thread)
        # one subscription per robot of this port: another port's requests never reach (nor cost) this link
        self._subs = [*(subscribe(self.session, robot_key(self.run_id, r, "linkreq"), enqueue) for r in sorted(self.robots) if r not in self._local),
                      *(subscribe(self.session, key, enqueue) for key in (*self._cmd_keys, *self._observe_keys)),
                      subscribe(self.session, estop_key(self.run_id), enqueue),
                      subscribe(self.session, self._estimate_key, enqueue),
                      watch_liveliness(self.session, coord_alive_key(self.run_id),
                                       lambda key, alive: self._events.put(("coord", parse_coord_token(key), alive))),
                      watch_liveliness(self.session, alive_wildcard(self.run_id), lambda key, alive: self._events.put(("agent", key, alive)))]
        token = declare_token(self.session, link_alive_key(self.run_id, self.port.name))  # agents notice a dead link at once
        reader = threading.Thread(target=self._read_loop, name=f"link-{self.port.name}-reader", daemon=True)
        reader.start()
        now = last_tick = time.monotonic()
        for robot in self.robots.values():
            robot.last_rx = now
        next_stats = now
        try:
            # the reader may start a waiting request at any time: look at the timers at least this often
            tick = self.timing.ack_timeout_s / 2
            while not self._stop.is_set():
                now = time.monotonic()
                with self._lock, self._writes.collect():
                    if now - last_tick > STALL_S:  # this process was stalled: the robots are not to blame
                        self._resume(now - last_tick)
                    last_tick = now
                    self._heartbeat(now)
                    if now >= next_stats:
                        self._publish_stats()
                        next_stats = now + self.timing.stats_period_s
                    self._check_timers(now)
                    wait = max(0.0, min(self._next_deadline(), next_stats, now + tick) - time.monotonic())
                try:
                    event = self._events.get(timeout=wait)
                except queue.Empty:
                    continue
                with self._lock, self._writes.collect():
                    self._handle_safely(event)
                    while True:  # drain what is queued before the timers again
                        try:
                            self._handle_safely(self._events.get_nowait())
                        except queue.Empty:
                            break
        finally:
            self._stop.set()
            token.undeclare()
            for sub in self._subs:
                sub.undeclare()
            reader.join(timeout=1.0)
            with self._lock:
                self._publish_stats()
        return 0

    # -- device -----------------------------------------------------------------------------

    def _read_loop(self) -> None:
        while not self._stop.is_set():
            try:
                data = self.device.read(QUIET_S)
            except OSError as exc:
                _log.error("port %s: read failed (%s); the link stops", self.port.name, exc)
                self._stop.set()
                return
            now = time.monotonic()
            frames = self.decoder.receive(data, now)
            if not frames:
                continue
            with self._lock, self._writes.collect():
                for frame in frames:
                    self._on_frame(frame, now)

    def _send(self, frame: Frame) -> bytes:
        wire = encode_frame(frame)
        self._write(frame.robot, wire)
        return wire

    def _write(self, robot_id: int, wire: bytes) -> None:
        """Put a frame on the port; it counts as a sign of life for robot ``robot_id``, which owes an answer from now."""
        self._writes.write(wire)
        self.counters.frames_sent += 1
        robot = self.robots.get(robot_id)
        if robot is not None:
            robot.last_tx = time.monotonic()
            if robot.unanswered_since is None:
                robot.unanswered_since = robot.last_tx

    def _feeding(self, robot: _Robot) -> bool:
        """Whether the link keeps ``robot`` alive (heartbeats, retransmissions): not once the coordinator or the
        robot's agent was seen and is gone (or the session to them was lost), so the robot's own watchdog stops it."""
        return not (self._coord_gone or robot.agent_gone)

    def _resume(self, stalled_s: float) -> None:
        """After a stall of this process: every robot's silence is counted again from the next frame sent to it,
        and a motion's timeout is moved by the stall."""
        _log.warning("port %s: the link was stalled for %.1f s; robots are judged again from now", self.port.name, stalled_s)
        for robot in self.robots.values():
            robot.unanswered_since = None
            for req in robot.requests():
                req.sent_at += stalled_s
                if req.accepted_at is not None:
                    req.accepted_at += stalled_s

    def _next_deadline(self) -> float:
        """The earliest time a heartbeat, retransmission or loss check is due."""
        t = self.timing
        due = math.inf
        for robot in self.robots.values():
            if robot.lost:
                continue
            if robot.control is not None:
                due = min(due, robot.control.due(t))
            if not self._feeding(robot):
                continue
            due = min(due, robot.last_tx + t.heartbeat_period_s)
            if robot.unanswered_since is not None:
                due = min(due, robot.unanswered_since + t.robot_timeout_s)
            for req in robot.requests():
                due = min(due, req.due(t))
                if req.accepted_at is not None:
                    due = min(due, req.accepted_at + t.motion_timeout_s)
        return due

    # -- events (engine thread) ----------------------------------------------------------------

    def _handle_safely(self, event: tuple[Any, ...]) -> None:
        """``_handle``; whatever a message holds, the link serves on (a failure is logged and counted)."""
        try:
            self._handle(event)
        except Exception:  # noqa: BLE001 - the port's only owner must not die of one message
            self.counters.rejected += 1
            _log.exception("port %s: a request could not be handled; dropped", self.port.name)

    def _handle(self, event: tuple[Any, ...]) -> None:
        if event[0] == "coord":
            self._on_coordinator(event[1], event[2])
        elif event[0] == "agent":
            self._on_agent(event[1], event[2])
        elif event[0] == "local":
            self._take(event[1])
        else:
            key, payload = event[1], event[2]
            if key in self._cmd_keys:
                self._on_ordered(self.robots[self._cmd_keys[key]], decode_or_drop(payload, self.drops, key, MotionCommand))
            elif key in self._observe_keys:
                self._on_ordered(self.robots[self._observe_keys[key]], decode_or_drop(payload, self.drops, key, ObserveRequest))
            elif key == self._estimate_key:
                msg = decode_or_drop(payload, self.drops, key, EstimateMessage)
                if msg is None or not self._coord_live:
                    return
                for robot, pose in zip(msg.ids, msg.poses, strict=True):
                    if robot in self.robots:
                        self.robots[robot].reckoned = (float(pose[0]), float(pose[1]), float(pose[2]))
            elif key == estop_key(self.run_id):
                stop = decode_or_drop(payload, self.drops, key, EmergencyStop)
                if stop is None:
                    return
                if stop.robots:  # a lost robot's stop: only the robots it names
                    stopped = [r.id for r in self.robots.values() if r.id in stop.robots and not r.lost]
                    for robot in stopped:
                        self._start_control(self.robots[robot], "estop", stop.step)
                else:
                    self._estop_all(stop.step)
                    stopped = sorted(r.id for r in self.robots.values() if not r.lost)
                if stopped:
                    ack = EstopAck(run=self.run_id, step=stop.step, stop_stamp_ns=stop.stamp_ns, by="link", name=self.port.name,
                                   robots=tuple(stopped))
                    publish(self.session, message_key(ack), encode(ack))
            else:
                req = decode_or_drop(payload, self.drops, key, LinkRequest)
                if req is None:
                    self.counters.rejected += 1
                    return
                self._take(req)

    def _take(self, req: LinkRequest, until: float | None = None) -> None:
        """A request, checked (``_authority``: held until ``until`` or dropped; ``_invalid``: dropped; both counted),
        then served."""
        if req.run != self.run_id:
            self._drop(f"run {req.run!r} is not this link's run {self.run_id!r}")
            return
        problem = self._authority(req)
        if problem == _HOLD:
            self._hold(req, until)
            return
        if problem is not None:
            self._drop(problem, unauthorised=True)
            return
        problem = self._invalid(req)
        if problem is not None:
            self._drop(problem)
            return
        self._on_request(req)

    def _drop(self, problem: str, unauthorised: bool = False) -> None:
        self.counters.rejected += 1
        self.counters.unauthorised += unauthorised
        _log.warning("port %s: request dropped: %s", self.port.name, problem)

    def _authority(self, req: LinkRequest) -> str | None:
        """None if ``req`` may go to the robot, ``_HOLD`` if that may still be proven, else why not.

        Emergency stops and resets always may. Anything else only while a coordinator is alive (held meanwhile: one
        taking the run over may appear). An observation only of the step the coordinator's latest ``ObserveRequest``
        for the robot asks (``robot/<id>/observe``). A command only as the coordinator commanded it: the coordinator's own
        ``MotionCommand`` of the same step (on ``robot/<id>/cmd``, which only its identity may publish), of the live
        run's epochs, with the same turn and (calibrated) drive, and only the robot's next step (a step already sent
        goes again only if the robot executed it, which it then answers from memory). Nothing for a robot whose
        agent's token went. The request's own claims (``start_pose``) count for nothing."""
        if req.kind in ("estop", "reset"):
            return None
        if not self._coord_live:
            return _HOLD
        robot = self.robots[req.robot]
        if robot.agent_gone:
            return f"robot {req.robot}: {req.kind} of step {req.step} while the robot's agent is gone"
        if req.kind == "observe":  # as the coordinator asked: a forged future step would make the robot refuse the real one
            asked = robot.asked
            if asked is None or asked.step < req.step or asked.epoch not in self._coord_epochs:
                return _HOLD
            stale = f"robot {req.robot}: observe of step {req.step} is stale: the coordinator asks step {asked.step}"
            return None if asked.step == req.step else stale
        who = f"robot {req.robot}: command of step {req.step}"
        if req.epoch not in self._coord_epochs:
            return f"{who} carries coordinator epoch {req.epoch}, not the live run's ({', '.join(map(str, sorted(self._coord_epochs)))})"
        in_flight = any(r.kind == "command" and r.step == req.step for r in (robot.busy, *robot.waiting) if r is not None)
        if not in_flight and (req.step < robot.commanded or (req.step == robot.commanded and not robot.executed)):
            return f"{who} is not the robot's next step (step {robot.commanded} was sent{' and executed' * robot.executed})"
        ordered = robot.ordered
        if ordered is None or ordered.step < req.step or ordered.epoch not in self._coord_epochs:
            return _HOLD
        if ordered.step > req.step:
            return f"{who} is stale: the coordinator commands step {ordered.step}"
        drive = self.calibration.get(req.robot, Calibration()).corrected_drive(ordered.drive_m)
        if not (math.isclose(req.turn_rad, ordered.turn_rad, rel_tol=1e-9, abs_tol=1e-12)
                and math.isclose(req.drive_m, drive, rel_tol=1e-9, abs_tol=1e-12)):
            return (f"{who} (turn {req.turn_rad:.6g} rad, drive {req.drive_m:.6g} m) is not the coordinator's "
                    f"(turn {ordered.turn_rad:.6g} rad, drive {drive:.6g} m)")
        return None

    def _hold(self, req: LinkRequest, until: float | None) -> None:
        """Keep ``req`` until its coordinator's command (or a coordinator) arrives, until ``until`` (default: the
        retry budget from now); then it is dropped and counted."""
        robot = self.robots[req.robot]
        same = (req.kind, req.step, req.turn_rad, req.drive_m, req.epoch)
        if any((held.kind, held.step, held.turn_rad, held.drive_m, held.epoch) == same for held, _ in robot.held):
            return  # a re-sent copy
        robot.held.append((req, time.monotonic() + self.timing.retry_budget_s if until is None else until))
        if len(robot.held) > MAX_HELD:
            self._drop(self._unproven(robot.held.pop(0)[0]), unauthorised=True)

    def _unproven(self, req: LinkRequest) -> str:
        if not self._coord_live:
            return f"robot {req.robot}: {req.kind} of step {req.step} while no coordinator is alive (only stops are sent)"
        return f"robot {req.robot}: command of step {req.step}, which no live coordinator commanded"

    def _retake(self, robot: _Robot) -> None:
        """Try the held requests of ``robot`` again (a coordinator or its command arrived)."""
        held, robot.held = robot.held, []
        for req, until in held:
            self._take(req, until)

    def _on_ordered(self, robot: _Robot, msg: MotionCommand | ObserveRequest | None) -> None:
        """The coordinator's command or observation request for ``robot`` (``None``: undecodable, already counted)."""
        if msg is None or msg.robot != robot.id:
            return
        if isinstance(msg, MotionCommand):
            robot.ordered = msg
        else:
            robot.asked = msg
        if robot.held:
            self._retake(robot)

    def _on_agent(self, key: str, alive: bool) -> None:
        """The liveliness token of an agent appeared or disappeared: keep feeding its robot or stop."""
        try:
            robot_id = parse_key(key).robot
        except KeyspaceError:
            return
        robot = None if robot_id is None else self.robots.get(robot_id)
        if robot is None:
            return
        if alive:
            robot.agent_seen, robot.agent_gone = True, False
            robot.unanswered_since = None
        elif robot.agent_seen:
            robot.agent_gone = True
            # once the coordinator has left, agents leaving is the run's normal end: not a warning
            _log.log(logging.INFO if self._coord_gone else logging.WARNING,
                     "port %s: the agent of robot %d is gone; the robot is no longer kept alive", self.port.name, robot.id)

    def _invalid(self, req: LinkRequest) -> str | None:
        """Why ``req`` must not reach a robot, or None: foreign, not representable on the wire, or beyond the limits.

        With a workspace configured the coordinator's command must carry its start pose, and the end is checked both
        from that pose and from the link's own ``reckoned`` pose of the robot (the coordinator's latest estimate moved
        by every motion the robot reported DONE since), never from the request's ``start_pose``."""
        robot = self.robots[req.robot]
        if req.step > MAX_U32:
            return f"step {req.step} does not fit the frame's u32 step"
        if req.kind in ("command", "observe") and robot.latest and req.step > robot.latest + MAX_STEP_AHEAD:
            return f"step {req.step} is more than {MAX_STEP_AHEAD} steps ahead of robot {req.robot}'s step {robot.latest}"
        if req.kind != "command":
            return None
        if not (fits_f32(req.turn_rad) and fits_f32(req.drive_m)):
            return f"turn {req.turn_rad!r} rad / drive {req.drive_m!r} m are not finite float32 values"
        driven = self.calibration.get(req.robot, Calibration()).driven(req.drive_m)
        ordered = robot.ordered.start_pose if robot.ordered is not None else ()
        pose = ordered if ordered and all(map(math.isfinite, ordered)) else ()
        if self.limits.workspace is not None and not pose:
            return f"robot {req.robot}: the coordinator's command has no start pose while a workspace is configured"
        problem = self.limits.refusal(dataclasses.replace(req, drive_m=driven, start_pose=pose))
        if problem is None and self.limits.workspace is not None and robot.reckoned is not None:
            problem = self.limits.refusal(dataclasses.replace(req, drive_m=driven, start_pose=robot.reckoned))
            problem = None if problem is None else f"from the link's reckoning of its pose, {problem}"
        return None if problem is None else f"robot {req.robot}: {problem}"

    def _reply(self, robot: int, step: int, kind: str, reason: str = "", parts: list[ObservationBody] | None = None) -> None:
        entries = [e for p in parts or [] for e in p.entries]
        msg = LinkReply(run=self.run_id, step=step, robot=robot, kind=kind, reason=reason,
                        observed=tuple(e[0] for e in entries), ranges=tuple(max(float(e[1]), 0.0) for e in entries),
                        bearings=tuple(float(e[2]) for e in entries))
        publish(self.session, message_key(msg), encode(msg))
        local = self._local.get(robot)
        if local is not None:
            local(msg)

    def _on_request(self, req: LinkRequest) -> None:
        robot = self.robots[req.robot]
        if robot.lost:
            self._reply(req.robot, req.step, "lost", f"robot {req.robot} stopped answering on port {self.port.name}")
            return
        if req.kind in ("estop", "reset"):
            self._start_control(robot, req.kind, req.step)
        elif robot.busy is None and robot.begin is None:
            self._start(robot, req)
        elif all((r.kind, r.step) != (req.kind, req.step) for r in (robot.busy, *robot.waiting) if r is not None):
            robot.waiting.append(req)  # a re-sent request already in flight or queued is not queued twice

    def _on_coordinator(self, token: tuple[int, int] | None, alive: bool) -> None:
        """A coordinator token ``(epoch, parent)`` appeared or disappeared. One whose parent is an epoch of the current
        run takes that run over (a standby or ``--resume``): the link feeds the robots again and keeps what is in
        flight. Any other one, with no coordinator alive, begins a new run (RUN to every robot); while one is alive
        it is a second master that the agents refuse, and ignored. When the last one is gone the link stops feeding."""
        if token is None:
            return
        epoch, parent = token
        if alive:
            if parent in self._coord_epochs:
                self._coord_epochs.add(epoch)
                self._coord_live.add(epoch)
                if self._coord_gone:
                    self._coord_gone = False
                    now = time.monotonic()
                    for robot in self.robots.values():
                        robot.unanswered_since = None  # judged again from the next frame sent to it
                        robot.last_rx = now
                    _log.warning("port %s: coordinator epoch %d took the run over from epoch %d; the robots are kept alive again",
                                 self.port.name, epoch, parent)
                    for robot in self.robots.values():
                        self._start_waiting(robot)
                        self._retake(robot)
            elif self._coord_live:
                _log.warning("port %s: coordinator epoch %d appeared while epoch %s runs; ignored", self.port.name, epoch,
                             ", ".join(map(str, sorted(self._coord_live))))
                return
            else:
                self._coord_epochs, self._coord_live = {epoch}, {epoch}
                self._coord_seen, self._coord_gone = True, False
                self._begin_run()
                for robot in self.robots.values():
                    self._retake(robot)  # requests that came before the coordinator's token was handled here
        else:
            self._coord_live.discard(epoch)
            if self._coord_seen and not self._coord_live and not self._coord_gone:
                self._coord_gone = True
                _log.warning("port %s: the coordinator is gone; the robots are no longer kept alive", self.port.name)
        self._publish_stats()

    def _begin_run(self) -> None:
        """The coordinator appeared: a new run. Forget the last run's requests and losses, send RUN (new epoch)."""
        self.counters.epoch = secrets.randbelow(MAX_U32) + 1
        now = time.monotonic()
        for robot in self.robots.values():
            robot.lost = False
            robot.last_rx = now
            robot.unanswered_since = None
            robot.reckoned = None
            robot.busy = robot.begin = None
            robot.waiting.clear()
            robot.latest = robot.commanded = 0
            robot.executed = False
            robot.ordered = robot.asked = None
            robot.begin = self._request(robot, "run", 0, FrameType.RUN, RunBody(self.counters.epoch))

    def _request(self, robot: _Robot, kind: str, step: int, frame_type: FrameType, body: Body) -> _Request:
        """Send a new request frame (next SEQ) to ``robot``; the ``_Request`` to track its answer."""
        seq = robot.next_seq()
        now = time.monotonic()
        return _Request(kind, step, seq, self._send(Frame.of(robot.id, seq, frame_type, body)), now, now)

    def _start(self, robot: _Robot, req: LinkRequest) -> None:
        robot.latest = max(robot.latest, req.step)
        if req.kind == "command":
            robot.busy = self._request(robot, req.kind, req.step, FrameType.COMMAND, MotionBody(req.step, req.turn_rad, req.drive_m))
            robot.busy.motion = (req.turn_rad, self.calibration.get(robot.id, Calibration()).driven(req.drive_m))
            robot.commanded, robot.executed = req.step, False
            pose = robot.ordered.start_pose if robot.ordered is not None else ()
            if robot.reckoned is None and pose:  # no estimate from the coordinator yet: start from its command's start pose
                robot.reckoned = (float(pose[0]), float(pose[1]), float(pose[2]))
        else:
            robot.busy = self._request(robot, req.kind, req.step, FrameType.OBSERVE, StepBody(req.step))

    def _start_control(self, robot: _Robot, kind: str, step: int) -> None:
        frame_type = FrameType.ESTOP if kind == "estop" else FrameType.RESET
        robot.control = self._request(robot, kind, step, frame_type, EmptyBody())

    def _estop_all(self, step: int) -> None:
        self._broadcast_seq = self._broadcast_seq % 0xFFFF + 1
        self._send(Frame.of(BROADCAST, self._broadcast_seq, FrameType.ESTOP, EmptyBody()))
        for robot in self.robots.values():
            if not robot.lost:
                self._start_control(robot, "estop", step)

    def _heartbeat(self, now: float) -> None:
        """HEARTBEAT to every robot that got no frame for ``heartbeat_period_s`` (any frame is a sign of life)."""
        stamp = int(now * 1000) & 0xFFFFFFFF
        for robot in self.robots.values():
            if now - robot.last_tx < self.timing.heartbeat_period_s or not self._feeding(robot):
                continue
            seq = robot.next_seq()
            self._send(Frame.of(robot.id, seq, FrameType.HEARTBEAT, HeartbeatBody(stamp)))
            self._heartbeats[(robot.id, seq)] = now
        if len(self._heartbeats) > 64 * len(self.robots):  # unanswered ones: keep the map bounded
            for key in list(self._heartbeats)[: len(self._heartbeats) // 2]:
                del self._heartbeats[key]

    def _rtt(self, sent: float, now: float) -> None:
        self.counters.rtts_ms.append((now - sent) * 1e3)

    def _on_frame(self, frame: Frame, now: float) -> None:
        robot = self.robots.get(frame.robot)
        if robot is None:
            return
        robot.last_rx = now
        robot.unanswered_since = None
        for pending in robot.requests():
            if frame.seq == pending.seq:
                pending.retries = 0  # the robot answers: the retry budget starts again
        try:
            body = frame.body()
        except FrameError as exc:
            _log.warning("port %s: robot %d sent a bad frame (%s)", self.port.name, frame.robot, exc)
            return
        kind = frame.type
        if kind == FrameType.HEARTBEAT_ACK:
            sent = self._heartbeats.pop((robot.id, frame.seq), None)
            if sent is not None:
                self._rtt(sent, now)
            return
        control = robot.control
        if control is not None and frame.seq == control.seq and kind in (FrameType.ESTOPPED, FrameType.RESET_ACK):
            self._rtt(control.sent_at, now)
            robot.control = None
            self._reply(robot.id, control.step, "estopped" if kind == FrameType.ESTOPPED else "reset")
            return
        begin = robot.begin
        if (begin is not None and frame.seq == begin.seq and kind == FrameType.RUN_ACK and isinstance(body, RunBody)
                and body.epoch == self.counters.epoch):
            self._rtt(begin.sent_at, now)
            robot.begin = None
            self._start_waiting(robot)
            return
        req = robot.busy
        if req is None or frame.seq != req.seq:
            return  # an answer to an older request (a late duplicate): already handled
        if not req.answered:
            self._rtt(req.sent_at, now)
            req.answered = True
        if kind == FrameType.ACCEPTED:
            if req.accepted_at is None:  # not forwarded: the agent waits for DONE (one message less per command)
                req.accepted_at = now
            return
        if kind == FrameType.DONE:
            robot.executed = robot.executed or req.kind == "command"  # the step in flight is the one last commanded
            if req.kind == "command" and robot.reckoned is not None:
                x, y, heading = robot.reckoned
                turn, driven = req.motion
                heading += turn
                robot.reckoned = (x + driven * math.cos(heading), y + driven * math.sin(heading), heading)
            self._finish(robot, "done")
        elif kind == FrameType.REFUSED and isinstance(body, RefusalBody):
            code = RefusalCode(body.code).name if body.code in set(RefusalCode) else str(body.code)
            self._finish(robot, "refused", f"robot {robot.id} refused ({code}): {body.reason}")
        elif kind == FrameType.ERROR and isinstance(body, ErrorBody):
            self._finish(robot, "refused", f"robot {robot.id} reported error {body.code}: {body.text}")
        elif kind == FrameType.OBSERVATION and isinstance(body, ObservationBody) and req.kind == "observe":
            req.parts[body.part] = body
            if len(req.parts) == body.parts and all(p.parts == body.parts for p in req.parts.values()):
                self._finish(robot, "observation", parts=[req.parts[i] for i in range(body.parts)])

    def _finish(self, robot: _Robot, kind: str, reason: str = "", parts: list[ObservationBody] | None = None) -> None:
        req = robot.busy
        assert req is not None  # called for the request in flight only
        robot.busy = None
        self._reply(robot.id, req.step, kind, reason, parts=parts)
        self._start_waiting(robot)

    def _start_waiting(self, robot: _Robot) -> None:
        while not self._coord_gone and robot.busy is None and robot.begin is None and robot.waiting:
            self._start(robot, robot.waiting.popleft())

    def _check_timers(self, now: float) -> None:
        t = self.timing
        for robot in self.robots.values():
            while robot.held and robot.held[0][1] <= now:
                self._drop(self._unproven(robot.held.pop(0)[0]), unauthorised=True)
            if robot.lost:
                continue
            feeding = self._feeding(robot)
            for req in robot.requests():
                if not feeding and req is not robot.control:
                    continue  # no longer kept alive: only an emergency stop is still sent
                if req.accepted_at is not None and now - req.accepted_at > t.motion_timeout_s:
                    self.counters.timeouts += 1
                    self._lose(robot, f"robot {robot.id} still executing the command of step {req.step} after "
                                      f"motion_timeout_s = {t.motion_timeout_s:g} s on port {self.port.name}")
                    break
                if now < req.due(t):
                    continue
                if req.retries >= t.max_retries:
                    self.counters.timeouts += 1
                    self._lose(robot, f"robot {robot.id} did not answer the {req.kind} of step {req.step} "
                                      f"after {req.retries} retransmissions on port {self.port.name}")
                    break
                self._write(robot.id, req.wire)  # the same frame, same SEQ
                self.counters.retransmissions += 1
                req.retries += 1
                req.sent_at = now
            silent = None if robot.unanswered_since is None else now - robot.unanswered_since
            if not robot.lost and feeding and silent is not None and silent > t.robot_timeout_s:
                self._lose(robot, f"robot {robot.id} silent for {silent:.1f} s on port {self.port.name}")

    def _lose(self, robot: _Robot, reason: str) -> None:
        _log.error("%s", reason)
        robot.lost = True
        pending: list[_Request | LinkRequest] = [*robot.requests(), *robot.waiting]
        step = max([r.step for r in pending], default=0)  # the step its agent waits on
        robot.busy = robot.control = robot.begin = None
        robot.waiting.clear()
        self._reply(robot.id, step, "lost", reason)

    def stats(self) -> LinkStats:
        """The counters now (any thread)."""
        with self._lock:
            rtts = list(self.counters.rtts_ms)
            d = dataclasses.replace(self.decoder.stats)
            lost = sorted(r.id for r in self.robots.values() if r.lost)
        return LinkStats(
            run=self.run_id, step=0, port=self.port.name, robots=tuple(sorted(self.robots)),
            frames_sent=self.counters.frames_sent, frames_received=d.frames, retransmissions=self.counters.retransmissions,
            crc_errors=d.crc_errors, length_errors=d.length_errors, skipped_bytes=d.skipped_bytes,
            timeouts=self.counters.timeouts, rejected=self.counters.rejected, unauthorised=self.counters.unauthorised,
            rtt_ms_median=statistics.median(rtts) if rtts else 0.0,
            rtt_ms_p90=statistics.quantiles(rtts, n=10)[-1] if len(rtts) >= 2 else (rtts[0] if rtts else 0.0),
            rtt_ms_max=max(rtts) if rtts else 0.0,
            lost=tuple(lost),
        )

    def _publish_stats(self) -> None:
        msg = self.stats()
        publish(self.session, message_key(msg), encode(msg))
