"""Emulated robots speaking the gateway frame protocol on pseudo-terminals (docs/emulator.md).

This is the complete robot side of docs/gateway-protocol.md, section "Reliability /
Robot side", for testing a gateway (``swarm link``) without hardware:

* ``EmulatedWorld``: the true poses of every robot of the run (one world, so sensing sees
  every robot) with the per-robot random streams ``SimDriver`` uses
  (``robot_rng(seed, id, MOTION)`` / ``SENSING``), so an emulated run draws the same
  numbers as a simulated agent given the same (float32-rounded) commands. Thread-safe.
* ``PortEmulator``: one serial/radio port. It opens a pty pair and serves the robots of
  the port on the master side; ``device`` (the slave, e.g. ``/dev/pts/5``) is opened by a
  link process exactly like a serial device. One reader thread decodes frames
  (``FrameDecoder``, ``resync()`` after 20 ms of quiet with a partial frame pending, as the
  protocol's "Receiving: resynchronisation" says) and runs the robots' state machines;
  motions end on timer threads so other robots and heartbeats keep being served.
* ``FaultPlan``: drops, corruption and delay of frames on the port, random or at fixed
  frame indices, counted and reported as events.
* ``TruthPublisher``: optional, like a motion-capture system: the robots' true poses as
  ``TruthMessage`` on Zenoh (step 0 at start, again whenever the coordinator's liveliness
  token appears, and step s when a robot handles OBSERVE of step s, before it answers).

Events (commands executed with their pose, duplicates suppressed, emergency stops with
``time.time_ns()``, watchdog stops, resets, injected faults) go to an ``on_event``
callback as plain dicts ``{"event": kind, "time_ns": ..., "port": ..., ...}``. The
callback runs on the emulator's threads while its state lock is held: it must be quick,
thread-safe and must not call back into the emulator.
"""

from __future__ import annotations

import heapq
import logging
import math
import os
import queue
import random
import select
import threading
import time
import tty
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, cast

import numpy as np

from robot_agent.write_batch import WriteBatch
from runtime.errors import SwarmInputError
from runtime.gateway.config import Calibration
from runtime.gateway.frames import (
    BROADCAST,
    MAX_ENTRIES,
    MAX_ROBOT,
    Body,
    EmptyBody,
    ErrorBody,
    ErrorCode,
    Frame,
    FrameDecoder,
    FrameError,
    FrameType,
    MotionBody,
    ObservationBody,
    RefusalBody,
    RefusalCode,
    RunBody,
    StepBody,
    encode_frame,
)
from runtime.models.config import ModelConfig
from runtime.models.motion import execute_command
from runtime.models.rng import Stream, robot_rng
from runtime.models.sensing import sense_robot
from runtime.wire.keys import coord_alive_key, validate_port, validate_run
from runtime.wire.messages import TruthMessage, encode, message_key
from runtime.wire.transport import publish, watch_liveliness

if TYPE_CHECKING:
    import zenoh

_log = logging.getLogger(__name__)

EventSink = Callable[[dict[str, Any]], None]
TruthListener = Callable[[int, int, np.ndarray], None]  # (robot, step, true pose)

POLL_S = 0.01  # reader poll period: resolution of the quiet timer and of the heartbeat watchdog
WRITE_TIMEOUT_S = 0.5  # a frame that cannot be written for this long (nobody reads the pty) is dropped
MAX_PARTS = 255  # OBSERVATION ``parts`` is a u8


class EmulatedWorld:
    """True poses of every robot of a run and their random streams (thread-safe).

    ``traj_ids``/``initial_poses`` (n, 3) as in ``Trajectory``; ``cfg`` the motion and
    sensing model; ``seed`` the run's seed. ``calibration`` gives robots true deviations
    (docs/gateway.md, ``Calibration``): a robot drives ``drive * motion_scale``, measures
    ``range + range_bias_m`` and ``bearing + bearing_offset_rad`` (wrapped); robots not in it
    are ideal. ``motion_time_s`` is the wall time a motion takes; ``heartbeat_timeout_s``
    the watchdog of every robot (gateway-protocol.md, Heartbeat watchdog).
    """

    physical = False  # True: motions happen in a physical world (``begin``), ``robot_agent.emulator_physics``

    def __init__(
        self,
        traj_ids: Iterable[int],
        initial_poses: np.ndarray,
        cfg: ModelConfig,
        seed: int,
        calibration: Mapping[int, Calibration] | None = None,
        motion_time_s: float = 0.0,
        heartbeat_timeout_s: float = 1.0,
    ) -> None:
        ids = tuple(int(r) for r in traj_ids)
        if len(set(ids)) != len(ids) or not ids:
            raise SwarmInputError(f"emulated robot ids must be distinct and at least one, got {list(ids)}")
        bad = [r for r in ids if not 0 <= r <= MAX_ROBOT]
        if bad:
            raise SwarmInputError(f"robot ids {bad} do not fit a frame's ROBOT field (0..{MAX_ROBOT})")
        poses = np.array(initial_poses, dtype=float)
        if poses.shape != (len(ids), 3) or not np.all(np.isfinite(poses)):
            raise SwarmInputError(f"initial poses must be {len(ids)} finite rows of [x, y, heading], got shape {poses.shape}")
        if not (math.isfinite(motion_time_s) and motion_time_s >= 0):
            raise SwarmInputError(f"motion time must be a finite number of seconds >= 0, got {motion_time_s!r}")
        if not (math.isfinite(heartbeat_timeout_s) and heartbeat_timeout_s > 0):
            raise SwarmInputError(f"heartbeat timeout must be a finite number of seconds > 0, got {heartbeat_timeout_s!r}")
        calibration = dict(calibration or {})
        unknown = sorted(set(calibration) - set(ids))
        if unknown:
            raise SwarmInputError(f"calibration given for robots {unknown} that are not in the run {list(ids)}")
        self.ids = ids
        self.cfg = cfg
        self.seed = int(seed)
        self.calibration = calibration
        self.motion_time_s = float(motion_time_s)
        self.heartbeat_timeout_s = float(heartbeat_timeout_s)
        self._index = {r: i for i, r in enumerate(ids)}
        self._poses = poses
        self._motion = {r: robot_rng(self.seed, r, Stream.MOTION) for r in ids}
        self._sensing = {r: robot_rng(self.seed, r, Stream.SENSING) for r in ids}
        self._truth_step = dict.fromkeys(ids, 0)
        self._claims: dict[int, str] = {}
        self._listeners: list[TruthListener] = []
        self._lock = threading.Lock()
        self._t0 = time.monotonic()

    def index(self, robot: int) -> int:
        """Row of ``robot`` in ``ids`` (and in ``poses()``)."""
        try:
            return self._index[robot]
        except KeyError:
            raise SwarmInputError(f"robot {robot} is not one of the emulated run's robots {list(self.ids)}") from None

    def pose(self, robot: int) -> np.ndarray:
        """True pose (3,) of ``robot`` now."""
        i = self.index(robot)
        with self._lock:
            return cast(np.ndarray, self._poses[i].copy())

    def poses(self) -> np.ndarray:
        """True poses (n, 3) of every robot, rows in ``ids`` order."""
        with self._lock:
            return self._poses.copy()

    def clock_ms(self) -> int:
        """The robots' clock (ms since the world was made, u32 wrapping), for OBSERVATION ``stamp_ms``."""
        return int((time.monotonic() - self._t0) * 1000) & 0xFFFFFFFF

    def claim(self, port: str, robots: Iterable[int]) -> None:
        """Mark ``robots`` as served by ``port``; ``SwarmInputError`` if unknown or served elsewhere."""
        robots = [int(r) for r in robots]
        for r in robots:
            self.index(r)
        with self._lock:
            taken = {r: self._claims[r] for r in robots if r in self._claims}
            if taken:
                raise SwarmInputError(f"robots {sorted(taken)} are already emulated on port(s) {sorted(set(taken.values()))}")
            self._claims.update(dict.fromkeys(robots, port))

    def release(self, port: str) -> None:
        """Forget the claims of ``port`` (when it closes)."""
        with self._lock:
            self._claims = {r: p for r, p in self._claims.items() if p != port}

    @property
    def emulated(self) -> list[int]:
        """The robots some port serves (sorted)."""
        with self._lock:
            return sorted(self._claims)

    def truth(self, robot: int) -> tuple[int, np.ndarray]:
        """(latest step ``robot`` was observed at, 0 before any OBSERVE; its true pose now)."""
        i = self.index(robot)
        with self._lock:
            return self._truth_step[robot], self._poses[i].copy()

    def add_truth_listener(self, listener: TruthListener) -> None:
        """Call ``listener(robot, step, pose)`` whenever a robot handles OBSERVE of a new step, before it senses."""
        with self._lock:
            self._listeners.append(listener)

    def remove_truth_listener(self, listener: TruthListener) -> None:
        with self._lock:
            if listener in self._listeners:
                self._listeners.remove(listener)

    def begin(self, robot: int, turn_rad: float, drive_m: float, step: int, done: Callable[[], None]) -> None:
        """A physical world starts the motion and calls ``done()`` when it is over; this one applies motions at once (``move``)."""
        raise NotImplementedError("the noise model's world moves a robot at once: move()")

    def halt(self, robot: int) -> None:
        """Stop a motion in progress (a physical world's; this one has none in progress)."""

    def close(self) -> None:
        """Release what the world holds (a physical world's stepping thread)."""

    def move(self, robot: int, turn_rad: float, drive_m: float) -> np.ndarray:
        """Execute (turn, drive) with ``robot``'s motion stream and true ``motion_scale``; its new true pose (3,)."""
        i = self.index(robot)
        command = np.array([turn_rad, self.calibration.get(robot, Calibration()).driven(drive_m)], dtype=float)
        with self._lock:
            self._poses[i] = execute_command(self._poses[i], command, self.cfg, self._motion[robot])
            return cast(np.ndarray, self._poses[i].copy())

    def sense(self, robot: int, step: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(observed ids, measured ranges m, bearings rad) of ``robot`` now, drawing from its sensing stream.

        With ``step``, the step is recorded as the robot's truth step and the truth
        listeners are told (robot, step, pose) before this returns.
        """
        i = self.index(robot)
        cal = self.calibration.get(robot, Calibration())
        with self._lock:
            if step is not None:
                self._truth_step[robot] = int(step)
            pose = self._poses[i].copy()
            listeners = list(self._listeners) if step is not None else []
            nb, rho, phi = sense_robot(self._poses, i, self.cfg, self._sensing[robot])
        if step is not None:
            for listener in listeners:
                listener(robot, int(step), pose)
        return np.array(self.ids, dtype=np.int64)[nb], cal.measured_ranges(rho), cal.measured_bearings(phi)


@dataclass(frozen=True)
class FaultPlan:
    """Faults injected on one port (per port: each port counts its own frames and has its own random stream).

    rx = frames from the gateway, tx = frames to the gateway. ``drop_prob``: each frame in
    either direction is lost with this probability. ``corrupt_prob``: one random byte of an
    outgoing frame is flipped. ``delay_s``: outgoing frames leave this much later (order
    kept). ``drop_rx``/``drop_tx``: 0-based indices of the valid frames received / frames
    sent on the port that are dropped for sure (e.g. ``drop_tx={0}`` loses the first
    answer). ``blackout`` = (step, seconds): the radio goes dead both ways for ``seconds`` from the
    moment a robot of the port accepts the COMMAND of ``step`` (once). ``seed`` seeds the random faults
    (with the port name).
    """

    drop_prob: float = 0.0
    corrupt_prob: float = 0.0
    delay_s: float = 0.0
    drop_rx: frozenset[int] = frozenset()
    drop_tx: frozenset[int] = frozenset()
    blackout: tuple[int, float] | None = None
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("drop_prob", "corrupt_prob"):
            p = getattr(self, name)
            if not (isinstance(p, (int, float)) and 0.0 <= p <= 1.0):
                raise SwarmInputError(f"fault {name} must be a probability in [0, 1], got {p!r}")
        if not (isinstance(self.delay_s, (int, float)) and math.isfinite(self.delay_s) and self.delay_s >= 0):
            raise SwarmInputError(f"fault delay_s must be a finite number of seconds >= 0, got {self.delay_s!r}")
        for name in ("drop_rx", "drop_tx"):
            indices = frozenset(getattr(self, name))
            if any(not isinstance(i, int) or i < 0 for i in indices):
                raise SwarmInputError(f"fault {name} must hold frame indices >= 0, got {sorted(indices, key=str)}")
            object.__setattr__(self, name, indices)
        if self.blackout is not None:
            step, seconds = self.blackout
            if not (isinstance(step, int) and step >= 1 and isinstance(seconds, (int, float)) and math.isfinite(seconds) and seconds > 0):
                raise SwarmInputError(f"fault blackout must be (step >= 1, seconds > 0), got {self.blackout!r}")

    @property
    def active(self) -> bool:
        return bool(self.drop_prob or self.corrupt_prob or self.delay_s or self.drop_rx or self.drop_tx or self.blackout)


@dataclass
class _Command:
    """A COMMAND a robot handled and the answer it keeps for retransmissions (type, body)."""

    seq: int
    step: int
    turn_rad: float
    drive_m: float
    answer: tuple[FrameType, Body]
    timer: threading.Timer | None = None


@dataclass
class _Robot:
    """State of one emulated robot (gateway-protocol.md, Robot side)."""

    robot: int
    last_cmd: _Command | None = None  # the last COMMAND handled, whatever its outcome
    moving: _Command | None = None  # accepted, motion in progress
    done: _Command | None = None  # the last COMMAND executed (DONE)
    obs_seq: int | None = None
    obs_step: int | None = None
    obs_parts: tuple[ObservationBody, ...] = ()
    estopped: bool = False
    last_rx: float | None = None  # monotonic time of the last frame for it; None: watchdog not started
    starved: bool = False  # stopped by the watchdog
    executed: int = 0
    epoch: int = 0  # the run the gateway began last (RUN); 0 before any

    def forget_steps(self) -> None:
        """A new run: no step memory (commands and observations of the last run)."""
        self.last_cmd = self.done = None
        self.obs_seq = self.obs_step = None
        self.obs_parts = ()

    def latest_step(self) -> int | None:
        steps = [c.step for c in (self.moving, self.done) if c is not None]
        return max(steps) if steps else None


@dataclass
class PortStats:
    """What happened on a port: frames each way, faults injected, decoder rejects."""

    rx_frames: int = 0
    tx_frames: int = 0
    rx_dropped: int = 0
    tx_dropped: int = 0
    tx_corrupted: int = 0
    tx_delayed: int = 0
    tx_overflow: int = 0  # frames lost because nobody read the pty for WRITE_TIMEOUT_S
    foreign_frames: int = 0  # frames for robots not on this port (ignored)
    crc_errors: int = 0
    length_errors: int = 0
    skipped_bytes: int = 0
    executed: dict[int, int] = field(default_factory=dict)


class PortEmulator:
    """The robots ``robots`` of ``world`` behind one port named ``port_name``, on a fresh pty.

    Ready on return: ``device`` is the path a link opens (raw mode is already set; open it
    with ``O_RDWR | O_NOCTTY``, or with pyserial). ``close()`` (or leaving the ``with``
    block) stops every thread and closes both pty ends. Behaviour: gateway-protocol.md,
    Robot side; what is modelled and what is not: docs/emulator.md.
    """

    def __init__(
        self,
        world: EmulatedWorld,
        port_name: str,
        robots: Iterable[int],
        faults: FaultPlan | None = None,
        on_event: EventSink | None = None,
    ) -> None:
        self.world = world
        self.port_name = validate_port(port_name)
        self.robots = tuple(int(r) for r in robots)
        if not self.robots or len(set(self.robots)) != len(self.robots):
            raise SwarmInputError(f"port {port_name}: robots must be distinct and at least one, got {list(self.robots)}")
        self.faults = faults or FaultPlan()
        self.on_event = on_event
        world.claim(self.port_name, self.robots)
        self._states = {r: _Robot(r) for r in self.robots}
        self._lock = threading.RLock()  # robot states, counters, fault stream
        self._tx_lock = threading.Lock()  # one frame at a time on the wire
        self._stop = threading.Event()
        self._closed = False
        self._stats = PortStats()
        self._overflow = 0
        self._blackout_until = -math.inf  # FaultPlan.blackout: the radio is dead until then (monotonic)
        self._decoder = FrameDecoder()
        self._writes = WriteBatch(self._write)  # the answers to one read's frames go out in one write
        self._fault_rng = random.Random(f"{self.faults.seed}/{self.port_name}")
        self._timers: set[threading.Timer] = set()
        self._delayed: list[tuple[float, int, bytes]] = []
        self._delay_cond = threading.Condition()
        self._master = self._slave = -1
        try:
            self._master, self._slave = os.openpty()
            tty.setraw(self._slave)
            os.set_blocking(self._master, False)
            self.device = os.ttyname(self._slave)
            self._reader = threading.Thread(target=self._read_loop, name=f"emulator-{port_name}-rx", daemon=True)
            self._sender = threading.Thread(target=self._delay_loop, name=f"emulator-{port_name}-tx", daemon=True)
            self._reader.start()
            if self.faults.delay_s > 0:
                self._sender.start()
        except BaseException:
            self._close_fds()
            world.release(self.port_name)
            raise

    # -- public ------------------------------------------------------------------------

    def __enter__(self) -> PortEmulator:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"PortEmulator({self.port_name!r}, device={getattr(self, 'device', None)!r}, robots={list(self.robots)})"

    def executed(self, robot: int) -> int:
        """How many COMMANDs ``robot`` has executed (DONE)."""
        with self._lock:
            return self._states[robot].executed

    def estopped(self, robot: int) -> bool:
        with self._lock:
            return self._states[robot].estopped

    def stats(self) -> PortStats:
        """A snapshot of the port's counters."""
        with self._lock:
            s = self._stats
            d = self._decoder.stats
            return PortStats(
                s.rx_frames, s.tx_frames, s.rx_dropped, s.tx_dropped, s.tx_corrupted, s.tx_delayed, self._overflow,
                s.foreign_frames, d.crc_errors, d.length_errors, d.skipped_bytes,
                {r: st.executed for r, st in self._states.items()},
            )

    def close(self) -> None:
        """Stop the threads, cancel motions in progress, close the pty (idempotent)."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            self._stop.set()
            timers = list(self._timers)
        with self._delay_cond:
            self._delay_cond.notify_all()
        for t in timers:
            t.cancel()
        for t in timers:
            t.join(timeout=2.0)
        self._reader.join(timeout=2.0)
        if self._sender.is_alive():
            self._sender.join(timeout=2.0)
        self._close_fds()
        self.world.release(self.port_name)

    # -- reading (reader thread) -----------------------------------------------------------

    def _read_loop(self) -> None:
        while not self._stop.is_set():
            try:
                ready, _, _ = select.select([self._master], [], [], POLL_S)
            except (OSError, ValueError):
                return  # fd closed
            data = b""
            if ready:
                try:
                    data = os.read(self._master, 4096)
                except BlockingIOError:
                    pass
                except OSError:  # EIO when no slave is open: cannot happen while we hold the slave, but don't spin
                    time.sleep(POLL_S)
            frames = self._decoder.receive(data, time.monotonic())  # with the quiet-line rule
            try:
                with self._writes.collect():
                    for frame in frames:
                        self._receive(frame)
                    self._watchdog(time.monotonic())
            except Exception:  # noqa: BLE001 - a bug must not silently kill every robot of the port: log and serve on
                _log.exception("port %s: error handling frames", self.port_name)

    def _receive(self, frame: Frame) -> None:
        """One valid frame from the gateway: faults, addressing, watchdog feed, then the robot's handler."""
        with self._lock:
            if self._closed:
                return
            index = self._stats.rx_frames
            self._stats.rx_frames += 1
            if self._blacked_out():
                self._stats.rx_dropped += 1
                return
            if self._lose(index, self.faults.drop_rx):
                self._stats.rx_dropped += 1
                self._event("fault", kind="drop_rx", index=index, robot=frame.robot, seq=frame.seq, type=frame.type)
                return
            if frame.robot == BROADCAST:
                targets = list(self.robots)
            elif frame.robot in self._states:
                targets = [frame.robot]
            else:
                self._stats.foreign_frames += 1
                return
            now = time.monotonic()
            for robot in targets:
                st = self._states[robot]
                # Handled in the state the frame found the robot in (a COMMAND reaching a starved
                # robot is refused NO_HEARTBEAT); then the frame counts as the gateway's sign of life.
                self._handle(st, frame, broadcast=frame.robot == BROADCAST)
                st.last_rx = now
                if st.starved:
                    st.starved = False
                    self._event("heartbeat_recovered", robot=robot)

    def _blacked_out(self) -> bool:
        """Whether the radio is dead now (``FaultPlan.blackout``)."""
        return time.monotonic() < self._blackout_until

    def _lose(self, index: int, fixed: frozenset[int]) -> bool:
        if index in fixed:
            return True
        return bool(self.faults.drop_prob) and self._fault_rng.random() < self.faults.drop_prob

    def _watchdog(self, now: float) -> None:
        timeout = self.world.heartbeat_timeout_s
        with self._lock:
            for st in self._states.values():
                if st.last_rx is not None and not st.starved and now - st.last_rx > timeout:
                    st.starved = True
                    self._event("heartbeat_timeout", robot=st.robot, silent_s=round(now - st.last_rx, 4))
                    self._abort(st, RefusalCode.NO_HEARTBEAT, f"no frame from the gateway for {timeout:g} s: stopped by the watchdog")

    # -- robot behaviour (called with self._lock held) ---------------------------------------

    def _handle(self, st: _Robot, frame: Frame, broadcast: bool) -> None:
        try:
            kind = FrameType(frame.type)
        except ValueError:
            kind = None
        if broadcast and kind is not FrameType.ESTOP:
            self._event("ignored", robot=st.robot, seq=frame.seq, type=frame.type, reason="broadcast is for ESTOP only")
            return
        if kind is None or kind >= 0x80:
            what = f"unknown frame type 0x{frame.type:02X}" if kind is None else f"0x{frame.type:02X} {kind.name} is an answer, not a request"
            self._error(st.robot, frame.seq, ErrorCode.UNKNOWN_TYPE, what)
            return
        try:
            body = frame.body()
        except FrameError as exc:
            self._error(st.robot, frame.seq, ErrorCode.BAD_BODY, f"{kind.name}: {exc}")
            return
        if kind is FrameType.COMMAND and isinstance(body, MotionBody):
            self._on_command(st, frame.seq, body)
        elif kind is FrameType.OBSERVE and isinstance(body, StepBody):
            self._on_observe(st, frame.seq, body.step)
        elif kind is FrameType.HEARTBEAT:
            self._send(st.robot, frame.seq, FrameType.HEARTBEAT_ACK, body)
        elif kind is FrameType.ESTOP:
            self._abort(st, RefusalCode.ESTOPPED, "emergency stop")
            st.estopped = True
            self._event("estop", robot=st.robot, seq=frame.seq, broadcast=broadcast)
            self._send(st.robot, frame.seq, FrameType.ESTOPPED, EmptyBody())
        elif kind is FrameType.RESET:
            was = st.estopped
            st.estopped = False
            self._event("reset", robot=st.robot, seq=frame.seq, was_estopped=was)
            self._send(st.robot, frame.seq, FrameType.RESET_ACK, EmptyBody())
        elif kind is FrameType.RUN and isinstance(body, RunBody):
            self._on_run(st, frame.seq, body.epoch)

    def _on_run(self, st: _Robot, seq: int, epoch: int) -> None:
        """RUN: a new epoch forgets the step memory (a motion still in progress is aborted); the
        epoch the robot is already in is only answered again (a retransmission)."""
        if epoch != st.epoch:
            self._abort(st, RefusalCode.OTHER, f"run {epoch} began")
            st.forget_steps()
            self._event("run", robot=st.robot, seq=seq, epoch=epoch, previous=st.epoch)
            st.epoch = epoch
        else:
            self._event("duplicate", robot=st.robot, type="RUN", seq=seq, epoch=epoch, answer="RUN_ACK")
        self._send(st.robot, seq, FrameType.RUN_ACK, RunBody(epoch))

    def _error(self, robot: int, seq: int, code: ErrorCode, text: str) -> None:
        self._event("error", robot=robot, seq=seq, code=int(code), text=text)
        self._send(robot, seq, FrameType.ERROR, ErrorBody(int(code), text))

    def _on_command(self, st: _Robot, seq: int, body: MotionBody) -> None:
        last = st.last_cmd
        if last is not None and seq == last.seq and body.step == last.step:
            self._resend(st, last, seq)  # retransmission: stored answer, nothing else
            return
        for known in (st.moving, st.done):
            if known is not None and body.step == known.step:  # same step under a new SEQ (restarted gateway)
                known.seq = seq  # its DONE / REFUSED (if still to come) answers the newest request
                st.last_cmd = known
                self._resend(st, known, seq)
                return
        latest = st.latest_step()
        if latest is not None and body.step < latest:
            self._refuse(st, seq, body, RefusalCode.OTHER, f"stale step {body.step}: the robot is at step {latest}")
            return
        if st.estopped:
            self._refuse(st, seq, body, RefusalCode.ESTOPPED, "emergency stop latched (RESET clears it)")
        elif st.starved:
            self._refuse(st, seq, body, RefusalCode.NO_HEARTBEAT,
                         f"stopped by the watchdog: no frame from the gateway for {self.world.heartbeat_timeout_s:g} s")
        elif st.moving is not None:
            self._refuse(st, seq, body, RefusalCode.BUSY, f"still executing step {st.moving.step}")
        elif not (math.isfinite(body.turn_rad) and math.isfinite(body.drive_m)) or body.drive_m < 0:
            self._refuse(st, seq, body, RefusalCode.LIMITS, f"turn {body.turn_rad} rad / drive {body.drive_m} m: need finite values, drive >= 0")
        else:
            cmd = _Command(seq, body.step, body.turn_rad, body.drive_m, (FrameType.ACCEPTED, StepBody(body.step)))
            st.last_cmd = st.moving = cmd
            self._event("accepted", robot=st.robot, seq=seq, step=body.step, turn_rad=body.turn_rad, drive_m=body.drive_m)
            self._send(st.robot, seq, FrameType.ACCEPTED, StepBody(body.step))
            blackout = self.faults.blackout
            if blackout is not None and body.step == blackout[0] and self._blackout_until == -math.inf:
                self._blackout_until = time.monotonic() + blackout[1]
                self._event("fault", kind="blackout", robot=st.robot, step=body.step, seconds=blackout[1])
            if self.world.physical:  # the world moves it now; DONE once the world is still
                self.world.begin(st.robot, body.turn_rad, body.drive_m, body.step, lambda: self._finish_later(st.robot, cmd))
            elif self.world.motion_time_s <= 0:
                self._finish(st, cmd)
            else:
                timer = threading.Timer(self.world.motion_time_s, self._finish_later, (st.robot, cmd))
                timer.daemon = True
                timer.name = f"emulator-{self.port_name}-motion-{st.robot}"
                cmd.timer = timer
                self._timers.add(timer)
                timer.start()

    def _refuse(self, st: _Robot, seq: int, body: MotionBody, code: RefusalCode, reason: str) -> None:
        answer = RefusalBody(body.step, int(code), reason)
        st.last_cmd = _Command(seq, body.step, body.turn_rad, body.drive_m, (FrameType.REFUSED, answer))
        self._event("refused", robot=st.robot, seq=seq, step=body.step, code=int(code), reason=reason)
        self._send(st.robot, seq, FrameType.REFUSED, answer)

    def _resend(self, st: _Robot, cmd: _Command, seq: int) -> None:
        kind, body = cmd.answer
        self._event("duplicate", robot=st.robot, type="COMMAND", seq=seq, step=cmd.step, answer=kind.name)
        self._send(st.robot, seq, kind, body)

    def _finish_later(self, robot: int, cmd: _Command) -> None:
        with self._lock:
            if cmd.timer is not None:
                self._timers.discard(cmd.timer)
            if not self._closed:
                self._finish(self._states[robot], cmd)

    def _finish(self, st: _Robot, cmd: _Command) -> None:
        """The motion of ``cmd`` ends: applied to the world at once, then DONE (unless it was aborted)."""
        if st.moving is not cmd:
            return
        pose = self.world.move(st.robot, cmd.turn_rad, cmd.drive_m)
        st.moving = None
        st.done = cmd
        st.executed += 1
        cmd.answer = (FrameType.DONE, StepBody(cmd.step))
        self._event("executed", robot=st.robot, seq=cmd.seq, step=cmd.step, pose=[float(v) for v in pose])
        self._send(st.robot, cmd.seq, FrameType.DONE, StepBody(cmd.step))

    def _abort(self, st: _Robot, code: RefusalCode, reason: str) -> None:
        """Stop a motion in progress: the robot stays where it is, the command is REFUSED with ``code``."""
        cmd = st.moving
        if cmd is None:
            return
        if cmd.timer is not None:
            cmd.timer.cancel()
            self._timers.discard(cmd.timer)
        st.moving = None
        self.world.halt(st.robot)
        cmd.answer = (FrameType.REFUSED, RefusalBody(cmd.step, int(code), reason))
        self._event("aborted", robot=st.robot, seq=cmd.seq, step=cmd.step, code=int(code), reason=reason)
        self._send(st.robot, cmd.seq, FrameType.REFUSED, cmd.answer[1])

    def _on_observe(self, st: _Robot, seq: int, step: int) -> None:
        if st.obs_step is not None and step == st.obs_step:
            self._event("duplicate", robot=st.robot, type="OBSERVE", seq=seq, step=step, answer="OBSERVATION", parts=len(st.obs_parts))
            st.obs_seq = seq
            for part in st.obs_parts:  # retransmission (or a new SEQ for the same step): no new sensing
                self._send(st.robot, seq, FrameType.OBSERVATION, part)
            return
        if st.obs_step is not None and step < st.obs_step:
            self._error(st.robot, seq, ErrorCode.OTHER, f"stale observe step {step}: step {st.obs_step} was already observed")
            return
        stamp = self.world.clock_ms()
        ids, ranges, bearings = self.world.sense(st.robot, step)  # truth listeners hear of it first
        entries = [(int(i), float(r), float(b)) for i, r, b in zip(ids, ranges, bearings, strict=True)]
        chunks = [entries[k:k + MAX_ENTRIES] for k in range(0, len(entries), MAX_ENTRIES)] or [[]]
        if len(chunks) > MAX_PARTS:
            self._error(st.robot, seq, ErrorCode.OTHER, f"{len(entries)} neighbours need {len(chunks)} parts, at most {MAX_PARTS}")
            return
        st.obs_seq, st.obs_step = seq, step
        st.obs_parts = tuple(ObservationBody(step, stamp, k, len(chunks), tuple(c)) for k, c in enumerate(chunks))
        self._event("observed", robot=st.robot, seq=seq, step=step, parts=len(chunks), entries=len(entries))
        for part in st.obs_parts:
            self._send(st.robot, seq, FrameType.OBSERVATION, part)

    # -- writing ---------------------------------------------------------------------------

    def _send(self, robot: int, seq: int, kind: FrameType, body: Body) -> None:
        """Encode an answer and put it on the wire, through the fault plan (called with self._lock held)."""
        data = bytearray(encode_frame(Frame.of(robot, seq, kind, body)))
        index = self._stats.tx_frames
        self._stats.tx_frames += 1
        if self._blacked_out():
            self._stats.tx_dropped += 1
            return
        if self._lose(index, self.faults.drop_tx):
            self._stats.tx_dropped += 1
            self._event("fault", kind="drop_tx", index=index, robot=robot, seq=seq, type=int(kind))
            return
        if self.faults.corrupt_prob and self._fault_rng.random() < self.faults.corrupt_prob:
            at = self._fault_rng.randrange(len(data))
            data[at] ^= self._fault_rng.randrange(1, 256)
            self._stats.tx_corrupted += 1
            self._event("fault", kind="corrupt", index=index, robot=robot, seq=seq, type=int(kind), byte=at)
        if self.faults.delay_s > 0:
            self._stats.tx_delayed += 1
            with self._delay_cond:
                heapq.heappush(self._delayed, (time.monotonic() + self.faults.delay_s, index, bytes(data)))
                self._delay_cond.notify()
        else:
            self._writes.write(bytes(data))

    def _delay_loop(self) -> None:
        while True:
            with self._delay_cond:
                while not self._stop.is_set() and (not self._delayed or self._delayed[0][0] > time.monotonic()):
                    wait = self._delayed[0][0] - time.monotonic() if self._delayed else None
                    self._delay_cond.wait(timeout=wait)
                if self._stop.is_set():
                    return
                _, _, data = heapq.heappop(self._delayed)
            self._write(data)

    def _write(self, data: bytes) -> None:
        view = memoryview(data)
        deadline = time.monotonic() + WRITE_TIMEOUT_S
        with self._tx_lock:
            while view:
                try:
                    view = view[os.write(self._master, view):]
                except BlockingIOError:
                    if time.monotonic() > deadline:
                        self._overflow += 1  # under _tx_lock only (the delay thread writes without _lock)
                        return
                    select.select([], [self._master], [], 0.05)
                except OSError:
                    return  # closed

    def _event(self, event: str, /, **fields: object) -> None:
        if self.on_event is None:
            return
        try:
            self.on_event({"event": event, "time_ns": time.time_ns(), "port": self.port_name, **fields})
        except Exception:  # noqa: BLE001 - the caller's callback must not break the port
            _log.exception("port %s: event callback failed", self.port_name)

    def _close_fds(self) -> None:
        for fd in (self._master, self._slave):
            if fd >= 0:
                try:
                    os.close(fd)
                except OSError:
                    pass
        self._master = self._slave = -1


class TruthPublisher:
    """The emulated robots' true poses on Zenoh, like a motion-capture system (for evaluation only).

    ``start()`` publishes ``TruthMessage(step=0)`` of every emulated robot and watches the
    coordinator's liveliness token ``swarm/<run>/alive/coord``: whenever it appears, every
    robot's latest truth (its latest observed step, its pose now) is published again. When a
    robot handles OBSERVE of step s, its ``TruthMessage(step=s)`` is published before it
    answers (from the port's reader thread, never from a Zenoh callback).
    """

    def __init__(self, world: EmulatedWorld, session: zenoh.Session, run_id: str) -> None:
        self.world = world
        self.session = session
        self.run_id = validate_run(run_id)
        self.published = 0
        self._jobs: queue.SimpleQueue[bool] = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._loop, name="emulator-truth", daemon=True)
        self._watch: zenoh.Subscriber[None] | None = None
        self._lock = threading.Lock()

    def __enter__(self) -> TruthPublisher:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def start(self) -> None:
        self.world.add_truth_listener(self._on_observe)
        self._thread.start()
        self._jobs.put(True)  # step 0 (or the latest) of every robot now
        self._watch = watch_liveliness(
            self.session, coord_alive_key(self.run_id), lambda key, alive: self._jobs.put(True) if alive else None
        )

    def close(self) -> None:
        self.world.remove_truth_listener(self._on_observe)
        if self._watch is not None:
            self._watch.undeclare()
            self._watch = None
        if self._thread.is_alive():
            self._jobs.put(False)
            self._thread.join(timeout=2.0)

    def _loop(self) -> None:
        while self._jobs.get():
            for robot in self.world.emulated:
                step, pose = self.world.truth(robot)
                self._publish(robot, step, pose)

    def _on_observe(self, robot: int, step: int, pose: np.ndarray) -> None:
        self._publish(robot, step, pose)

    def _publish(self, robot: int, step: int, pose: np.ndarray) -> None:
        msg = TruthMessage(run=self.run_id, step=step, robot=robot, pose=tuple(float(v) for v in pose))
        try:
            publish(self.session, message_key(msg), encode(msg))
        except Exception:  # noqa: BLE001 - a closed session at shutdown must not break a robot's answer
            _log.warning("truth of robot %d (step %d) not published", robot, step, exc_info=True)
            return
        with self._lock:
            self.published += 1
