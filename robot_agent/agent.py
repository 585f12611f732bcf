"""The agent process of one robot: executes commands through its driver and reports observations.

One ``Agent`` per robot opens a Zenoh *client* session to the run's hub, declares its
liveliness token ``swarm/<run>/alive/robot/<id>`` and serves (docs/protocol.md):

* ``MotionCommand`` on ``.../robot/<id>/cmd``: decoded with the run's ids (a bad message
  is dropped and counted, never fatal; if its header still names this robot's run and
  step, the refusal ``refusal_status`` is published too, echoing whatever ``cmd_id`` it
  carried, so a coordinator never acts on it). Refusals nobody's real command needs (a bad
  message, a stale or out-of-sequence step, a command after an emergency stop) are published
  at most ``REFUSAL_BURST`` at once and ``REFUSALS_PER_S`` a second; the others are only counted
  (``refusals.suppressed``), so a flood of forged commands is not answered one for one. Only the next step is executed: a command
  for step s is checked when s = (last observed step) + 1 (the coordinator observes every
  robot after every step, so a real command always follows the observation of the step
  before); then ``CommandLimits`` (``Status refused`` with the reason), else ``Status
  accepted``, executed through the driver, ``Status done``. Every ``Status`` echoes the
  command's ``cmd_id``. The same step again (a re-send) re-publishes the last ``Status``
  and never executes twice; a lower step is refused as stale and a later one as out of
  sequence, neither remembered.
* ``ObserveRequest`` on ``.../robot/<id>/observe``: answered with an
  ``ObservationReport`` for that step; a duplicate step re-publishes the same report
  (no new sensing, so random streams stay aligned with the in-process simulator). Only
  the next step is sensed (step 1 first); other steps are dropped and counted, so a
  forged or replayed request never consumes a sensing draw.

Synchronisation of simulated sensing (``driver.simulated``): sensing needs every
robot's true pose *after* step s, so an agent

1. first publishes its own ``TruthMessage(step=s)`` on ``swarm/<run>/sim/truth/<id>``: right
   after its ``Status done`` if it moved in step s (the coordinator gathers the truths during the
   command round), else on ``ObserveRequest(step=s)`` (and again on a re-sent request),
2. then waits (while still serving other messages) for the coordinator's
   ``TruthSetMessage(step=s)`` on ``swarm/<run>/sim/truths``, which the coordinator
   sends once it holds the step-s truth of every robot of the run (one message per
   agent and step instead of one per robot),
3. then senses and publishes its ``ObservationReport(step=s)``.

Only the truth set of the pending step is used (a real one always follows this agent's own
truth of that step; one that overtook its step's request, which Zenoh may deliver later as it
travels on another key, is kept until the request comes); others are dropped and counted. A simulated agent also
publishes its current truth as step 0 at start and whenever the coordinator's liveliness
token ``swarm/<run>/alive/coord`` appears, so a coordinator learns the initial true poses
for evaluation without any sensing (which would consume the sensing stream).

One master at a time (docs/protocol.md, Coordinator epochs): every coordinator declares its
token ``coord_alive_key(run, epoch, parent)`` and stamps its commands, observation requests and
truth sets with its ``epoch``. The agent obeys one epoch: the first live coordinator whose
message it gets binds it, and while that token lives every other epoch is refused (a command
answered ``Status refused`` naming the live epoch, other messages dropped as foreign); a message
of an epoch whose token went (a dead or replayed coordinator) or without any epoch is refused,
one of an epoch whose token has not reached the agent yet is dropped (its coordinator sends it
again). An epoch that was taken over stays refused, also when its token comes back once its successor is gone
(a coordinator that stalled beyond its session lease; its session re-declares the token when it resumes: it
steps down on the refusal). A coordinator that names the bound epoch as its ``parent`` proves that epoch gone (it
declares itself only once that token is gone), even before the agent saw the token go. When
the bound token is gone the next live coordinator may bind it: one that names the agent's epoch (or an
ancestor) as its ``parent`` took the run over and continues it, so the step memory is kept (a command for
the step already executed is answered from memory, never executed twice); any other starts a new run at
step 1 and the agent forgets the last run's steps (an emergency stop stays latched), so ``swarm coordinator`` can run again against the same
agents (and, through the link's RUN handshake, the same robots). An agent without any step
memory (just started, e.g. a lost robot's agent restarted), or whose last command it refused (the coordinator
dropped it, e.g. after its watchdog stopped it), answers an observation request of any later step of the
coordinator it obeys: that is how a lost robot rejoins a run in progress. Meanwhile it ignores the run's truth
sets without counting them as drops.

Emergency stop: an ``EmergencyStop`` on ``swarm/<run>/estop`` naming this robot (or no
robot: the whole run) is forwarded to the driver at once by a thread of its own (``driver.estop``: a gateway driver sends it to its link, even
while the loop waits for a motion to finish); every later command is refused. The same thread
acknowledges every stop it acted on with an ``EstopAck`` on ``swarm/<run>/estop/ack`` (``swarm
estop`` counts them). Limits
(``CommandLimits``: drive, turn, and the workspace checked from the command's
``start_pose``, the coordinator's estimate of the robot) are checked before the driver
sees a command. A driver that raises ``DriverRefused`` gives ``Status refused`` with its
reason; ``RobotLost`` (during a command: after a ``Status refused`` "robot lost: ...")
drops the liveliness token (the coordinator reports the robot lost by id) and ends the
loop (``run`` returns 3); so does ``driver.report_lost`` while idle. Any other exception from
``execute`` or ``sense``, or no return within ``command_timeout_s`` (when set: the call then runs
on a thread of its own and is abandoned), is a driver fault (``DriverFault``, a ``RobotLost``):
the robot is reported lost the same way and ``driver.estop`` is called first. Whenever the loop
ends, ``driver.stop()`` then ``driver.detach()`` are called (docs/drivers.md). The token is
declared only once ``driver.ready`` (a gateway driver: its link process is up), so "agent
alive" means "robot reachable".

The loop runs on the caller's thread; Zenoh callbacks only enqueue. ``stop()`` (called
by the SIGTERM/SIGINT handlers of ``swarm agent``) ends it and the session is closed.
``run(session)`` serves on a session its host opened instead (``robot_agent.host``: many
agents in one process, one session); on the wire the agent is the same (its own keys,
token, driver and random streams), and the host closes the session.
"""

from __future__ import annotations

import contextlib
import functools
import logging
import queue
import threading
import time
from collections.abc import Callable, Collection
from typing import TYPE_CHECKING, Any, Protocol, cast

import numpy as np

from robot_agent.driver import Driver, DriverFault, DriverRefused, PeerPoses, RobotLost
from runtime.wire.keys import alive_key, coord_alive_key, estop_key, parse_coord_token, robot_key, truths_key
from runtime.wire.messages import (
    RUN_STOPPED_REFUSAL,
    CommandLimits,
    DropCounter,
    EmergencyStop,
    EstopAck,
    Message,
    MessageError,
    MotionCommand,
    ObservationReport,
    ObserveRequest,
    Status,
    TruthMessage,
    TruthSetMessage,
    decode,
    decode_or_drop,
    encode,
    message_key,
    refusal_status,
)
from runtime.wire.rate_limit import RateLimit
from runtime.wire.transport import ZenohSettings, claim_identities, declare_token, open_session, publish, subscribe, watch_liveliness

if TYPE_CHECKING:
    import zenoh

_log = logging.getLogger(__name__)
_COORD = "__coord_alive__"
_LOST = "__driver_lost__"  # the driver lost its robot while idle (e.g. the gateway's link process died)
_STOP = "__stop__"  # wakes the loop so it sees stop()
_UNSEEN = "__unseen__"  # a coordinator epoch whose token has not reached this agent yet
READY_TIMEOUT_S = 30.0  # how long an agent waits for its driver (link process) before declaring its token
REFUSALS_PER_S = 20.0  # refusals of commands that answer no real command, on average ...
REFUSAL_BURST = 20  # ... and at once


class Inbox(Protocol):
    """Where an agent's Zenoh callbacks and ``stop()`` put ``(key, payload)``: its own queue, or a host's feed."""

    def put(self, item: tuple[str, bytes]) -> None: ...


class Agent:
    """Robot ``robot`` of the run ``run`` with robots ``ids``, driving ``driver``."""

    def __init__(
        self,
        settings: ZenohSettings,
        run: str,
        robot: int,
        ids: Collection[int],
        driver: Driver,
        limits: CommandLimits = CommandLimits(),
        ready_timeout_s: float = READY_TIMEOUT_S,
        command_timeout_s: float | None = None,
    ) -> None:
        self.settings = settings
        self.run_id = run
        self.robot = int(robot)
        self.ids = sorted(int(i) for i in ids)
        self.known = frozenset(self.ids)
        self.driver = driver
        self.limits = limits
        self.ready_timeout_s = float(ready_timeout_s)
        self.command_timeout_s = command_timeout_s  # None: the driver's calls are not timed (built-in drivers bound their own)
        self.drops = DropCounter(_log)
        self.refusals = RateLimit(REFUSALS_PER_S, REFUSAL_BURST)
        self.executed = 0  # commands executed (for tests and logs)
        self._stop = threading.Event()
        self._queue: queue.SimpleQueue[tuple[str, bytes]] = queue.SimpleQueue()  # ``run``'s inbox; put() is signal-safe
        self._inbox: Inbox = self._queue  # where callbacks and stop() put messages (``open`` may be given another)
        self._subs: list[Any] = []
        self._forwarder: threading.Thread | None = None
        self._token: zenoh.LivelinessToken | None = None
        self._last_cmd_step = -1
        self._last_cmd: MotionCommand | None = None
        self._last_status: Status | None = None
        self._last_obs_step = -1
        self._last_report: ObservationReport | None = None
        self._last_truth: TruthMessage | None = None
        self._pending: int | None = None  # step of an ObserveRequest waiting for truths
        self._peers: PeerPoses | None = None  # the pending step's truth set (simulation)
        self._early: tuple[int, PeerPoses] | None = None  # a truth set that came before its step's request
        self._session: zenoh.Session | None = None
        self._cmd_key = robot_key(run, self.robot, "cmd")
        self._observe_key = robot_key(run, self.robot, "observe")
        self._estop_key = estop_key(run)
        self._stops: queue.SimpleQueue[EmergencyStop | None] = queue.SimpleQueue()  # for the forwarder thread
        self.estopped = False
        self._run_stop: str | None = None  # the refusal's reason once the whole run was e-stopped
        self.lost_reason: str | None = None
        self._coords: dict[int, int] = {}  # live coordinator tokens: epoch -> parent
        self.bound: int | None = None  # the epoch obeyed (its token may have gone since)
        self._lineage: set[int] = set()  # epochs of the run the step memory belongs to
        self._gone: set[int] = set()  # epochs whose tokens this agent saw go

    def stop(self) -> None:
        """Ask the loop to end (safe from a signal handler or another thread)."""
        self._stop.set()
        self._inbox.put((_STOP, b""))

    @property
    def stopped(self) -> bool:
        """Whether ``stop()`` was called (or the agent ended)."""
        return self._stop.is_set()

    def run(self, session: zenoh.Session | None = None) -> int:
        """Serve until ``stop()`` (returns 0) or until the robot is lost (returns 3).

        Without ``session`` the agent opens its own from ``settings`` and closes it on
        return, refusing (``SwarmInputError``) a robot that already has a live agent; with one (its host's, shared
        with other agents) it leaves it open.
        """
        own = session is None
        with open_session(self.settings) if own else contextlib.nullcontext(cast("zenoh.Session", session)) as session:
            if own:  # a host checks its robots itself, once
                claim_identities(session, self.run_id, [self.robot])
            self.open(session)
            while not self._stop.is_set():
                if not self.serve(*self._queue.get()):
                    break
            self.close()
        return self.outcome()

    def open(self, session: zenoh.Session, inbox: Inbox | None = None) -> None:
        """Attach the driver and start serving on ``session``: subscriptions (enqueueing into ``inbox``, by default
        the agent's own), the stop forwarder, the liveliness token; a simulated robot publishes its step-0 truth.
        A host that serves several agents from one thread (``robot_agent.host``) passes one inbox per agent that
        feeds its shared queue, and calls ``serve`` for each message and ``close`` at the end."""
        if inbox is not None:
            self._inbox = inbox
        self._session = session
        self.driver.attach(session)
        self.driver.on_lost = lambda reason: self._inbox.put((_LOST, reason.encode()))  # lost while idle ends the agent too
        self._wait_for_driver()
        enqueue = lambda key, payload: self._inbox.put((key, payload))  # noqa: E731 (Zenoh thread: enqueue only)
        self._subs = [subscribe(session, self._cmd_key, enqueue), subscribe(session, self._observe_key, enqueue),
                      subscribe(session, self._estop_key, self._on_estop)]
        self._forwarder = threading.Thread(target=self._forward_estop, name=f"agent-{self.robot}-estop", daemon=True)
        self._forwarder.start()
        if self.driver.simulated:
            self._subs.append(subscribe(session, truths_key(self.run_id), enqueue))
        self._subs.append(watch_liveliness(session, coord_alive_key(self.run_id),
                                           lambda key, alive: self._inbox.put((_COORD, f"{key} {int(alive)}".encode()))))
        self._token = declare_token(session, alive_key(self.run_id, self.robot))
        if self.driver.simulated:
            self._publish_truth(0)
        _log.info("robot %d of run %s ready (robots %s)", self.robot, self.run_id, self.ids)

    def serve(self, key: str, payload: bytes) -> bool:
        """Handle one message of the inbox; False once the agent is to end (``stop()``, or its robot lost)."""
        if key != _STOP:
            try:
                self._handle(key, payload)
            except RobotLost as e:
                self.lost_reason = str(e)
                _log.error("robot %d lost: %s; dropping the liveliness token", self.robot, e)
                if isinstance(e, DriverFault):  # the robot's state is unknown: stop it for good
                    self._bounded(self.driver.estop, max(self._last_cmd_step, 0))
                return False
            except Exception:  # noqa: BLE001 - a bug must not silently kill a robot mid-run: log it and keep serving
                _log.exception("robot %d: error handling a message on %s", self.robot, key)
        return not self._stop.is_set()

    def close(self) -> None:
        """Stop serving: drop the token and subscriptions, end the stop forwarder (after the stops queued), then
        ``driver.stop()`` and ``driver.detach()``; the session stays open."""
        if self._token is not None:
            self._token.undeclare()
        for sub in self._subs:
            sub.undeclare()
        self._stops.put(None)  # ends the forwarder once it forwarded the stops queued: none reaches a detached driver
        if self._forwarder is not None:
            self._forwarder.join(timeout=1.0)
        self._bounded(self.driver.stop)
        self._bounded(self.driver.detach)
        self._stop.set()
        self._session = None

    def outcome(self) -> int:
        """``run``'s status once closed: 3 if the robot was lost, else 0 (drops and refusals logged)."""
        if self.drops.total:
            _log.warning("robot %d dropped %d bad messages: %s", self.robot, self.drops.total, self.drops.snapshot())
        if self.refusals.suppressed:
            _log.warning("robot %d left %d refusals unsent (rate limit)", self.robot, self.refusals.suppressed)
        return 3 if self.lost_reason is not None else 0

    def _driver_call(self, fn: Callable[..., Any], *args: Any) -> Any:
        """``fn(*args)`` of the driver: ``DriverRefused`` and ``RobotLost`` pass; any other exception, or no return
        within ``command_timeout_s`` (if set), raises ``DriverFault``."""
        what = getattr(fn, "__name__", "call")
        if self.command_timeout_s is None:
            try:
                return fn(*args)
            except (DriverRefused, RobotLost):
                raise
            except Exception as e:  # a driver's bug is a fault of that robot, not of the agent
                raise DriverFault(f"driver error in {what}: {type(e).__name__}: {e}") from e
        box: list[tuple[bool, Any]] = []
        done = threading.Event()

        def target() -> None:
            try:
                box.append((True, fn(*args)))
            except BaseException as e:  # noqa: BLE001 - handed to the loop thread
                box.append((False, e))
            done.set()

        threading.Thread(target=target, name=f"agent-{self.robot}-{what}", daemon=True).start()
        if not done.wait(self.command_timeout_s):
            raise DriverFault(f"the driver's {what} did not return within {self.command_timeout_s:g} s")
        ok, value = box[0]
        if ok:
            return value
        if isinstance(value, (DriverRefused, RobotLost)):
            raise value
        raise DriverFault(f"driver error in {what}: {type(value).__name__}: {value}") from value

    def _bounded(self, fn: Callable[..., Any], *args: Any) -> None:
        """Call ``fn(*args)`` (estop, stop, detach at the end) and log a failure; with a command timeout, give up
        waiting after that long (a hung driver must not keep the agent from ending)."""
        try:
            self._driver_call(fn, *args)
        except RobotLost as e:
            _log.error("robot %d: %s", self.robot, e)

    def _wait_for_driver(self) -> None:
        """Until the driver can reach the robot (a gateway driver: its link process is up), so the
        liveliness token, declared next, means "this robot can be commanded"; at most ``ready_timeout_s``."""
        deadline = time.monotonic() + self.ready_timeout_s
        while not self._stop.is_set() and not self.driver.ready(0.1):
            if time.monotonic() > deadline:
                _log.warning("robot %d: its driver is not ready after %.1f s (no link process? no robot in its ROS 2 namespace?); serving anyway",
                             self.robot, self.ready_timeout_s)
                return

    # -- emergency stop (Zenoh thread -> forwarder thread) -----------------------------------

    def _on_estop(self, key: str, payload: bytes) -> None:
        msg = decode_or_drop(payload, self.drops, key, EmergencyStop)
        if msg is not None and msg.applies_to(self.robot):
            if not msg.robots and self._run_stop is None:
                self._run_stop = f"{RUN_STOPPED_REFUSAL} by {msg.source} ({msg.reason})"
            self.estopped = True
            self._stops.put(msg)

    def _forward_estop(self) -> None:
        """Forwarder thread: the first stop goes to the driver; every stop is acknowledged."""
        forwarded = False
        while (msg := self._stops.get()) is not None:
            if not forwarded:
                _log.warning("robot %d: emergency stop", self.robot)
                try:
                    self.driver.estop(max(self._last_cmd_step, 0))
                except Exception:  # noqa: BLE001 - not acknowledged: the stop may not have reached the robot
                    _log.exception("robot %d: the driver failed to forward the emergency stop", self.robot)
                    continue
                forwarded = True
            ack = EstopAck(run=self.run_id, step=msg.step, stop_stamp_ns=msg.stamp_ns, by="agent", name=str(self.robot),
                           robots=(self.robot,))
            try:
                self._send(ack)
            except Exception:  # noqa: BLE001 - a closed session at shutdown: the stop itself went out
                _log.warning("robot %d: could not acknowledge the emergency stop", self.robot)

    # -- message handling (loop thread only) --------------------------------------------

    def _send(self, msg: Message) -> None:
        assert self._session is not None, "while running only"
        publish(self._session, message_key(msg), encode(msg))

    def _on_coordinator(self, event: str) -> None:
        """A coordinator's token appeared or went; a simulated agent answers a new one (not while it obeys
        another live one) with its current truth as step 0, so a new coordinator learns the start."""
        key, alive = event.rsplit(" ", 1)
        token = parse_coord_token(key)
        if token is None:
            return
        epoch, parent = token
        if alive == "0":
            self._coords.pop(epoch, None)
            self._gone.add(epoch)
            return
        obeying = self.bound is not None and self.bound in self._coords
        self._coords[epoch] = parent
        if self.driver.simulated and not obeying:
            self._publish_truth(0)

    def _admit(self, epoch: int) -> str | None:
        """None if a message of coordinator ``epoch`` is to be obeyed (binding the agent to it), ``_UNSEEN`` if that
        epoch's token has not reached this agent yet (the message is dropped: its coordinator sends it again), else
        why not. An epoch whose token has not arrived is unseen even while another is obeyed: its messages can overtake
        the token events (another subscription) of a takeover, when the old token's end has not arrived either."""
        if epoch != 0 and epoch not in self._coords and epoch not in self._gone:
            return _UNSEEN
        if self.bound is not None and self.bound in self._coords:
            if epoch == self.bound:
                return None
            if self._coords.get(epoch) != self.bound:
                return (f"coordinator epoch {epoch} refused: robot {self.robot} obeys the live coordinator epoch {self.bound} "
                        f"of run {self.run_id}")
            self._coords.pop(self.bound)  # it took over from ours, which declared after our token had gone: gone
            self._gone.add(self.bound)
        if epoch in self._lineage and epoch != self.bound:  # its token came back after another took its run over
            return (f"coordinator epoch {epoch} refused: robot {self.robot} obeys coordinator epoch {self.bound}, which took "
                    f"run {self.run_id} over from it")
        if epoch not in self._coords:
            what = "carries no coordinator epoch" if epoch == 0 else f"comes from coordinator epoch {epoch}, which is gone"
            return f"refused: the message {what} (run {self.run_id})"
        if self._coords[epoch] not in self._lineage:  # a new run: forget the last run's steps (a stop stays latched)
            self._last_cmd_step, self._last_cmd, self._last_status = -1, None, None
            self._last_obs_step, self._last_report = -1, None
            self._pending, self._peers, self._early = None, None, None
            self._lineage = set()
        self._lineage.add(epoch)
        self.bound = epoch
        _log.info("robot %d obeys coordinator epoch %d of run %s", self.robot, epoch, self.run_id)
        return None

    def _handle(self, key: str, payload: bytes) -> None:
        if key == _LOST:
            raise RobotLost(payload.decode())
        if key == _COORD:
            self._on_coordinator(payload.decode())
        elif key == self._cmd_key:
            self._on_command(key, payload)
        elif key == self._observe_key:
            msg = decode_or_drop(payload, self.drops, key, ObserveRequest, self.known)
            if msg is not None and self._obeyed(key, msg):
                self._on_observe(msg)
        else:
            decoded = _decode_truths(payload, self.known, key)
            if isinstance(decoded, MessageError):
                self.drops.drop(key, decoded)
            elif self._obeyed(key, decoded[0]):
                self._on_truths(*decoded)

    def _obeyed(self, key: str, msg: ObserveRequest | TruthSetMessage) -> bool:
        """Whether ``msg`` comes from the coordinator obeyed; if not it is dropped as foreign."""
        reason = self._admit(msg.epoch)
        if reason is not None:
            problem = f"coordinator epoch {msg.epoch} is not known yet" if reason == _UNSEEN else reason
            self.drops.drop(key, MessageError(f"{msg.TYPE}.epoch", problem, "foreign"))
        return reason is None

    def _on_command(self, key: str, payload: bytes) -> None:
        try:
            cmd = decode(payload, MotionCommand, self.known, key=key)
        except MessageError as e:
            self.drops.drop(key, e)
            refusal = refusal_status(e)
            if refusal is not None and refusal.run == self.run_id and refusal.robot == self.robot and self.refusals.allow():
                self._send(refusal)  # not remembered as handled: a valid command for that step still runs
            return
        why = self._admit(cmd.epoch)
        if why == _UNSEEN:
            self.drops.drop(key, MessageError("MotionCommand.epoch", f"coordinator epoch {cmd.epoch} is not known yet", "foreign"))
            return
        if why is not None:
            self._status(cmd, "refused", why, remember=False)
            return
        if cmd.step < self._last_cmd_step:
            self._status(cmd, "refused", f"stale step {cmd.step}: step {self._last_cmd_step} was already handled", remember=False)
            return
        if cmd.step == self._last_cmd_step and self._last_status is not None:
            self._answer_again(cmd)  # duplicate: never execute twice
            return
        if self.estopped:
            self._status(cmd, "refused", self._run_stop or "emergency stop", remember=False)
            return
        expected = self._next_step
        if cmd.step != expected:
            self._status(cmd, "refused", f"out of sequence: step {cmd.step}, the next step of this robot is {expected}", remember=False)
            return
        self._last_cmd_step, self._last_cmd = cmd.step, cmd
        reason = self.limits.refusal(cmd)
        if reason is not None:
            self._status(cmd, "refused", reason)
            return
        if not self.driver.instantaneous:  # a motion that takes time: say it is under way
            self._status(cmd, "accepted")
        try:
            self._driver_call(self.driver.execute, cmd)
        except DriverRefused as e:  # a run-wide stop that reached the driver first is said as the run's stop
            self._status(cmd, "refused", (self._run_stop if self.estopped else None) or str(e) or "refused")
            return
        except RobotLost as e:  # say why in the command's status, then the loop drops the token
            self._status(cmd, "refused", f"robot lost: {e}", remember=False)
            raise
        self.executed += 1
        self._status(cmd, "done")
        if self.driver.simulated:  # the pose after the motion, while the others still move: see _on_observe
            self._publish_truth(cmd.step)

    def _answer_again(self, cmd: MotionCommand) -> None:
        """The answer to a command for the step already handled: a re-send gets the same ``Status``; the same
        motion from the coordinator that took the run over gets that answer with its own ``cmd_id``."""
        last, done = self._last_status, self._last_cmd
        assert last is not None  # called when the step was answered
        if cmd.cmd_id == last.cmd_id or done is None:
            self._send(last)
        elif (cmd.turn_rad, cmd.drive_m) != (done.turn_rad, done.drive_m):
            self._status(cmd, "refused", f"step {cmd.step} was already handled with another motion "
                                         f"(turn {done.turn_rad:.6g} rad, drive {done.drive_m:.6g} m)", remember=False)
            return
        else:
            self._status(cmd, last.state, last.reason, remember=False)
        if last.state == "done" and self._truth_published(cmd.step):
            assert self._last_truth is not None, "_truth_published"
            self._send(self._last_truth)  # the truth that followed the done may be lost too (or went to the coordinator taken over)

    @property
    def _outside(self) -> bool:
        """Whether this robot is outside the run's steps, so the coordinator may ask it to rejoin at a later step: it
        has no step memory (just started, e.g. restarted after a crash), or it refused its last command (the
        coordinator dropped it: a robot its watchdog stopped is re-admitted at the next configuration)."""
        if self._pending is not None:
            return False
        if self._last_cmd_step < 0 and self._last_obs_step < 0:
            return True
        last = self._last_status
        return last is not None and last.state == "refused" and last.step == self._last_cmd_step > self._last_obs_step

    @property
    def _next_step(self) -> int:
        """The only step this robot may move or sense at next: the coordinator observes every robot after every
        step, so a real command or request always follows the observation of the step before (step 1 first)."""
        return max(self._last_obs_step, 0) + 1

    def _status(self, cmd: MotionCommand, state: str, reason: str = "", *, remember: bool = True) -> None:
        """Publish this robot's ``Status`` answering ``cmd``; ``remember`` it as the answer a re-sent command gets."""
        status = Status(run=self.run_id, step=cmd.step, robot=self.robot, state=state, reason=reason, cmd_id=cmd.cmd_id)
        if remember:
            self._last_status = status
        elif not self.refusals.allow():
            return  # an answer to no real command, beyond the rate limit: counted only
        self._send(status)

    def _on_observe(self, req: ObserveRequest) -> None:
        if req.step == self._last_obs_step and self._last_report is not None:
            if self._truth_published(req.step):
                assert self._last_truth is not None, "_truth_published"
                self._send(self._last_truth)
            self._send(self._last_report)
            return
        expected = self._pending if self._pending is not None else self._next_step
        if self._outside and req.step >= expected:
            expected = req.step  # join the run at its coordinator's step (a lost robot rejoining)
        if req.step != expected:
            self.drops.drop(self._observe_key, MessageError(
                "ObserveRequest.step", f"{req.step} out of sequence (expected step {expected})", "out-of-range"))
            return
        first = self._pending is None
        self._pending = req.step
        if self._early is not None and self._early[0] == req.step:
            self._peers = self._early[1]
        self._early = None
        if self.driver.simulated and not (first and self._truth_published(req.step)):
            self._publish_truth(req.step)  # not again after this step's motion (a re-sent request gets it again)
        self._try_report()

    def _on_truths(self, msg: TruthSetMessage, poses: PeerPoses) -> None:
        """The truth set ``msg`` with its ``poses`` by robot (shared read-only by the agents of a process)."""
        if msg.step != self._pending:
            if self._pending is None and msg.step == self._next_step and self._truth_published(msg.step):
                self._early = (msg.step, poses)  # Zenoh does not keep the order of different keys: its request is on the way
                return
            passed_by = self._outside and (msg.step > self._next_step or self._last_cmd_step >= 0)  # a step made without it
            if msg.step != self._last_obs_step and not passed_by:  # a late duplicate of the last set is normal, and so are
                # the sets of the steps the run makes while this robot is outside them (before it rejoins); nothing else
                self.drops.drop(truths_key(self.run_id), MessageError(
                    "TruthSetMessage.step", f"{msg.step} is not the pending step {self._pending}", "out-of-range"))
            return
        self._peers = poses
        self._try_report()

    def _truth_published(self, step: int) -> bool:
        """Whether this agent's latest ``TruthMessage`` is of ``step``."""
        return self._last_truth is not None and self._last_truth.step == step

    def _publish_truth(self, step: int) -> None:
        pose = self.driver.true_pose()
        if pose is None:  # a tracker's or simulator's truth that has not come (yet): nothing to tell
            _log.warning("robot %d: no true pose for step %d (the driver has none yet)", self.robot, step)
            return
        self._last_truth = TruthMessage(run=self.run_id, step=step, robot=self.robot, pose=tuple(pose.tolist()))
        self._send(self._last_truth)

    def _try_report(self) -> None:
        step = self._pending
        if step is None:
            return
        if self.driver.simulated and self._peers is None:
            return  # waiting for the step's truth set
        observed, ranges, bearings = self._driver_call(self.driver.sense, self._peers, step)
        report = ObservationReport(
            run=self.run_id, step=step, robot=self.robot, observed=observed, ranges=ranges, bearings=bearings
        )
        self._pending, self._peers = None, None
        self._last_obs_step, self._last_report = step, report
        self._send(report)


_TRUTHS_LOCK = threading.Lock()


def _decode_truths(payload: bytes, known: frozenset[int], key: str) -> tuple[TruthSetMessage, PeerPoses] | MessageError:
    """A ``TruthSetMessage`` and its poses (or why it is bad), decoded once per process: the agents a host runs
    (``robot_agent.host``) all receive the same set of every robot's pose each step, at the same moment. The
    lock makes the first decode and the others wait for its cached result (without it all 50 threads of a host
    missed the cache together and decoded the 500-pose set 50 times: most of a 500-agent step's CPU)."""
    with _TRUTHS_LOCK:
        return _decode_truths_once(payload, known, key)


@functools.lru_cache(maxsize=4)
def _decode_truths_once(payload: bytes, known: frozenset[int], key: str) -> tuple[TruthSetMessage, PeerPoses] | MessageError:
    try:
        msg = decode(payload, TruthSetMessage, known, key=key)
    except MessageError as e:
        return e
    return msg, PeerPoses(np.array(msg.ids, dtype=np.int64), np.array(msg.poses, dtype=float).reshape(len(msg.ids), 3))
