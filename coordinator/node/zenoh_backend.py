"""The distributed swarm backend: the executor's ``SwarmBackend`` over Zenoh (docs/protocol.md).

``ZenohSwarmBackend`` talks to one agent per robot through an open session:

* ``execute(step)``: the next global step number s (motion steps from 1);
  ``MotionCommand`` (step s, a fresh random ``cmd_id``) to each moving robot, then waits
  until every one of them answered ``Status done`` carrying that ``cmd_id``.
* ``observe()``: ``ObserveRequest`` (step s) to every robot; waits for every robot's
  ``ObservationReport`` of step s (and, for simulated agents, its ``TruthMessage``: a robot
  that moved sent it with its ``Status done``, so it is usually in already) and returns the
  observations in the order of ``ids`` (the in-process simulator's order). The step's
  ``TruthSetMessage`` goes out once every truth is in, never before the requests.
* ``true_poses()``: the latest truths of the robots (simulation), or None.
* ``take_lost()``: the robots lost since the last call (see below), dropped from ``ids``.

It is also the executor's ``ExecutorListener`` (pass it as ``listener=``):
``on_plan`` publishes ``PlanMessage`` on ``swarm/<run>/coord/plan`` (``config`` 1-based,
``step`` the plan's first step, groups as robot ids) and makes the following
``MotionCommand``s carry that ``config``; ``on_estimate`` publishes ``EstimateMessage``
on ``swarm/<run>/coord/estimate`` (step 0: the initial estimate, then after every step)
and makes the following commands carry the robot's estimated pose as ``start_pose``.
Without a listener call the commands carry ``config`` 0.

Only answers to real commands count: a ``Status`` is used only if it is for the current
step and carries the ``cmd_id`` sent to that robot; reports and truths only for the
current step from robots still in the run. Everything else is dropped and counted
(``drops``, reason ``foreign``), never acted on.

Lost robots (docs/failure-model.md): a robot is lost when its liveliness token disappears
(noticed at once, whatever the coordinator is doing: the Zenoh callback hands it to a
stopper thread), when it has not answered a command or observation request of a step
within ``timeouts.step_s`` (each is re-sent once at half that), or when it refuses its
command. A lost robot gets an ``EmergencyStop`` naming it and a ``RobotEvent`` ``lost``
at once; the waits stop waiting for it and the simulated truth sets leave it out; the
executor learns of it through ``take_lost()``.
All Zenoh callbacks only enqueue or set flags; the waiting happens on the caller's thread.

One master per run (docs/protocol.md, Coordinator epochs): the backend draws its ``epoch``
(random, 63 bits, never 0), stamps every ``MotionCommand``, ``ObserveRequest`` and
``TruthSetMessage`` with it and declares its token ``coord_alive_key(run, epoch, parent)``
only if no other coordinator's token of the run is alive, and gives up (``CoordinatorConflict``
naming the live one) if another appeared meanwhile. ``parent`` is the epoch whose run it takes
over (0: a new run); ``resume(state)`` then starts at the checkpoint's step.
``publish_checkpoint`` publishes the executor's ``RunState`` as a ``Checkpoint``.

Stalls (docs/failure-model.md): a coordinator stalled beyond its session lease (10 s: swapped out,
SIGSTOP) loses its session to the hub, and every robot's token disappears from its view at once, with
the hub (its own token goes from its own view too). Its session is back within milliseconds, but it
holds the hub's tokens again only once the hub has re-sent them: until then a liveliness query answers
from an empty view. So a token gone while the view is *unsettled* (the session lost the hub, or this
process stalled: a turn of the stopper thread or of a wait longer than ``STALL_S``, within the last
``RESYNC_S``; or this coordinator's own token, which comes back with the hub's tokens, is not in its view)
is no robot lost: the robot is *suspect* and judged once the view has settled (its token alive then, it
never was lost). Every judgement of a gone token asks the hub first for the run's tokens,
coordinators' included, in queries whose answers must hold this coordinator's own token (a liveliness
query on a session that also watches tokens sometimes answers empty, or without some of the hub's tokens: two
such answers united, ``hub_view``).
When a coordinator whose ``parent`` is this epoch is alive (a standby took the run over meanwhile: seen
in that answer or announced by its token) or an agent refuses a command because it obeys another live
coordinator, this one *steps down*: ``SteppedDown`` (a ``CoordinatorConflict``) at its next wait, and from
then on it declares no robot lost and sends nothing. A run-wide ``EmergencyStop`` heard while the run is in progress ends it (``RunStopped``):
a coordinator never commands a stopped run. A robot that refuses a command because its watchdog
stopped it (``NO_HEARTBEAT``: its link or radio stalled) did not move and is still served by its agent:
it is dropped like a lost robot but gets no emergency stop, and it is re-admitted at the next
configuration like a rejoining robot (``take_rejoining``).
"""

from __future__ import annotations

import logging
import queue
import re
import secrets
import threading
import time
from collections.abc import Callable, Collection, Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from coordinator.backend import BackendEnded
from coordinator.checkpoint import RunState
from coordinator.legs import LegRecord
from runtime.errors import RunConflictError, SwarmConnectionError, SwarmInputError, SwarmRunError
from runtime.gateway.frames import RefusalCode
from runtime.models.state import Observations, StepCommands, SwarmEstimate
from runtime.wire.keys import (
    alive_wildcard,
    coord_alive_key,
    estop_key,
    parse_coord_token,
    parse_key,
    robot_wildcard,
    run_wildcard,
    truth_wildcard,
)
from runtime.wire.messages import (
    MAX_MESSAGE_BYTES,
    RUN_STOPPED_REFUSAL,
    Checkpoint,
    ContactMessage,
    DropCounter,
    EmergencyStop,
    EstimateMessage,
    MessageError,
    MotionCommand,
    ObservationReport,
    ObserveRequest,
    PlanMessage,
    RobotEvent,
    Status,
    TruthMessage,
    TruthSetMessage,
    decode_or_drop,
    encode,
    message_key,
    observations_from_reports,
)
from runtime.wire.transport import alive_now, declare_token, publish, subscribe, watch_liveliness

if TYPE_CHECKING:
    import zenoh

    from coordinator.plan import Plan
    from coordinator.run_result import ContactEvent
    from coordinator.selection.selector import Selection

_log = logging.getLogger(__name__)
CHECKPOINT_STATE_CHARS = MAX_MESSAGE_BYTES - 2**14  # the state of a Checkpoint, with room for its other fields


STALL_S = 1.0  # s: a turn of a wait loop (a 0.05 s pump) this long means this process stalled, not the robots
WATCHDOG_REFUSAL = f"({RefusalCode.NO_HEARTBEAT.name})"  # in a refusal's reason: the robot's watchdog had stopped it (link)
HUB_GRACE_S = 3.0  # s without the hub after which the run ends (HubLost): a stalled coordinator's session is back in ms
SETTLE_S = 0.02  # s a token gone waits before its robot is judged: the time a closing session takes to drop its hub
RESYNC_S = 1.0  # s a view is unsettled after its session lost the hub or this process stalled (the hub re-sends its tokens in ms)
VIEW_TRIES = 9  # liveliness queries at most for a view (a run with nothing live, asked without a token of its own, asks them all: ~0.26 s)
VIEW_ANSWERS = 2  # complete answers united into the view (one may still miss a token of the hub's)
VIEW_PAUSE_S = 0.001  # s before the second query, doubling before each later one (empty answers come in runs of ms)
OTHER_MASTER = re.compile(r"refused: robot \d+ obeys ")  # an agent's refusal: another coordinator holds (or held) the run


class AgentError(SwarmRunError):
    """A robot agent failed the run; ``robots`` names the robot ids."""


class AgentLost(AgentError):
    """Agents that did not come up at the start of the run."""


class HubLost(AgentError, SwarmConnectionError):
    """This coordinator's own connection to the hub (router) is gone: no message reaches any robot any more."""

    def __init__(self, message: str) -> None:
        super().__init__(message, [])


class CoordinatorConflict(RunConflictError):
    """Another coordinator's token of the run is alive: a run has one master at a time."""


class SteppedDown(CoordinatorConflict, BackendEnded):
    """Another coordinator took this one's run over (it stalled beyond its session lease): it steps down."""


class RunStopped(AgentError, BackendEnded):
    """A run-wide ``EmergencyStop`` was heard: the run ends, nothing more is commanded."""


def hub_view(session: zenoh.Session, key_expr: str, own: int | None = None, timeout_s: float = 1.0) -> tuple[set[str], bool]:
    """The keys of the tokens alive on ``key_expr`` and whether they are complete: the union of ``VIEW_ANSWERS``
    answers that show the hub's view. With ``own`` (``key_expr`` covers the coordinator tokens of its run, and this
    session declared the token of coordinator epoch ``own``), an answer shows it if it holds that token; without
    (a session that declared none there: the check before a coordinator starts, a replay's, a status), if it is not
    empty, and every answer is united. A liveliness query on a session that also watches the tokens sometimes answers
    empty, in runs of a few ms (tens, more than 31 ms, under load), or without some of the hub's tokens (Zenoh 1.10):
    asked at most ``VIEW_TRIES`` times, pausing ``VIEW_PAUSE_S``, doubled each time, between the queries (an empty view
    without ``own`` takes them all: about 0.26 s).
    Without an answer that shows the hub's view: (the last answer, False), without ``own`` (the union, False)."""
    keys: set[str] = set()
    last: set[str] = set()
    complete = 0
    for k in range(VIEW_TRIES):
        if k:
            time.sleep(VIEW_PAUSE_S * 2 ** (k - 1))
        last = alive_now(session, key_expr, timeout_s)
        shows = bool(last) if own is None else any((token := parse_coord_token(key)) is not None and token[0] == own for key in last)
        if shows or own is None:
            keys |= last
        if shows:
            complete += 1
            if complete == VIEW_ANSWERS:
                break
    return (keys, complete > 0) if complete or own is None else (last, False)


@dataclass(frozen=True)
class LiveRun:
    """A run's liveliness tokens at the hub (``live_run``): the robots whose agents are alive, the live coordinators
    (``{epoch: parent}``) and whether the answers showed the hub's view (``hub_view``)."""

    robots: frozenset[int]
    coordinators: dict[int, int]
    complete: bool


def live_run(session: zenoh.Session, run: str, timeout_s: float = 1.0, own: int | None = None) -> LiveRun:
    """The tokens of ``run`` alive at the hub, agents' and coordinators' (``hub_view`` of ``swarm/<run>/**``; ``own``:
    the coordinator epoch whose token ``session`` declared)."""
    keys, complete = hub_view(session, run_wildcard(run), own, timeout_s)
    robots: set[int] = set()
    coordinators: dict[int, int] = {}
    for key in keys:
        token = parse_coord_token(key)
        if token is not None:
            coordinators[token[0]] = token[1]
            continue
        try:
            robot = parse_key(key).robot
        except Exception:  # noqa: BLE001 - a key outside the key space is not a robot's token
            continue
        if robot is not None:
            robots.add(robot)
    return LiveRun(frozenset(robots), coordinators, complete)


def live_coordinators(session: zenoh.Session, run: str, timeout_s: float = 1.0, own: int | None = None) -> dict[int, int]:
    """The coordinators of ``run`` whose tokens are alive: ``{epoch: parent}``, ``hub_view``'s answer (``own``: the
    epoch whose token ``session`` declared; without, a spurious empty answer is asked past too)."""
    keys = hub_view(session, coord_alive_key(run), own, timeout_s)[0]
    tokens = (parse_coord_token(key) for key in keys)
    return dict(t for t in tokens if t is not None)


def conflict_message(run: str, live: dict[int, int]) -> str:
    """One line naming the live coordinators of ``run``."""
    names = ", ".join(f"epoch {e}" + (f" (took over epoch {p})" if p else "") for e, p in sorted(live.items()))
    return (f"run {run} already has a live coordinator ({names}, token {coord_alive_key(run)}): one master per run; "
            f"stop it first, or start this one with --standby to take over when it is gone")


@dataclass(frozen=True)
class Timeouts:
    """Seconds to wait: for the agents at start, and for every answer of a step."""

    start_s: float = 30.0
    step_s: float = 5.0


def _robots(ids: list[int]) -> str:
    return f"robot {ids[0]}" if len(ids) == 1 else f"robots {', '.join(map(str, ids))}"


class ZenohSwarmBackend:
    """``SwarmBackend`` of the agents of run ``run`` with robots ``ids``, over ``session``."""

    def __init__(self, session: zenoh.Session, run: str, ids: Collection[int], timeouts: Timeouts = Timeouts(), simulated: bool = True,
                 parent: int = 0, rejoin: bool = True, robot_radius_m: float = 0.0) -> None:
        live = live_coordinators(session, run)
        if live:
            raise CoordinatorConflict(conflict_message(run, live))
        self.epoch = secrets.randbits(63) or 1
        self.parent = parent
        self.rejoin = rejoin  # a lost robot whose token comes back may rejoin (take_rejoining)
        self._dropped_warned = False  # a checkpoint left out the estimate's carried fields (said once)
        self._back: set[int] = set()  # lost robots whose token came back (guarded by _lock)
        self.superseded: str | None = None  # why this coordinator steps down (another one holds the run)
        self.stopped_by: str | None = None  # a run-wide emergency stop heard, by whom
        # whether this process is being stopped (its stop signal, e.g. a Ctrl-C that reached the agents too): their tokens
        # then go with the stop itself and no robot is declared lost (the caller sets it; any thread may call it)
        self.stop_requested: Callable[[], bool] = lambda: False
        self._suspect: set[int] = set()  # robots whose token went while the session had lost the hub (stopper thread)
        self._session_lost = False  # the coordinator's Zenoh link lost the hub at least once (this process stalled beyond its lease)
        self._stalled_at = -1e9  # monotonic time a wait or the stopper thread last noticed this process had stalled
        self._link_lost_at = -1e9  # monotonic time the session was last seen without the hub (its own token gone from its view)
        self._own_alive = True  # this coordinator's own token is in its own view (it comes back with the hub's tokens)
        self._hub_gone_since: float | None = None  # monotonic time the Zenoh link was first seen without the hub (since back)
        self.session = session
        self.radius = robot_radius_m  # the run's body radius, stated in each ContactMessage
        self.run = run
        self.ids = np.array(sorted(int(i) for i in ids), dtype=np.int64)  # robots still in the run
        self._id_list = self.ids.tolist()
        self._id_set = set(self._id_list)
        self.known = frozenset(self._id_list)  # every robot of the run (decoding)
        self.timeouts = timeouts
        self.simulated = simulated
        self.step = 0  # last global step number used
        self.config = 0  # 1-based configuration of the current plan (0 before on_plan)
        self.drops = DropCounter(_log)
        self._inbox: queue.SimpleQueue[tuple[str, bytes]] = queue.SimpleQueue()  # C-level: cheapest for the Zenoh thread
        self._lock = threading.Lock()
        self._alive: set[int] = set()
        self._started = False  # after wait_for_agents: a token that disappears is a lost robot
        self._lost: dict[int, str] = {}  # every robot lost so far (guarded by _lock)
        self._hub_lost: str | None = None  # why this process lost its connection to the hub (then no robot is lost)
        self._untaken: dict[int, str] = {}  # lost, not yet reported by take_lost (guarded by _lock)
        self._stops: queue.Queue[tuple[int, str | None, float] | None] = queue.Queue()  # (robot, reason, stop it?) or
        # (robot, None, when its token went)
        self._truth: dict[int, tuple[int, np.ndarray]] = {}
        self._truth_now: set[int] = set()  # robots whose truth of the current step is in
        self._truths_sent = 0  # last step whose TruthSetMessage went out
        self._asked = 0  # last step whose ObserveRequests went out (its truth set never precedes them)
        self._owed_done: set[int] = set()  # robots whose Status done the command round still needs (O(1) per message)
        self._owed_obs: set[int] = set()  # robots whose report (and truth) the observation round still needs
        self._estimate: dict[int, list[float]] | None = None  # latest published pose per robot: commands' start_pose
        self._cmds: dict[int, MotionCommand] = {}
        self._reports: dict[int, ObservationReport] = {}
        self._status: dict[int, Status] = {}
        self._stopper = threading.Thread(target=self._stop_lost, name="coordinator-lost-robots", daemon=True)
        self._stopper.start()
        enqueue = lambda key, payload: self._inbox.put((key, payload))  # noqa: E731 (Zenoh thread: enqueue only)
        self._subs = [
            subscribe(session, robot_wildcard(run, "status"), enqueue),
            subscribe(session, robot_wildcard(run, "obs"), enqueue),
            subscribe(session, truth_wildcard(run), enqueue),
            watch_liveliness(session, alive_wildcard(run), self._on_liveliness),
            watch_liveliness(session, coord_alive_key(run), self._on_coordinator),
            subscribe(session, estop_key(run), self._on_estop),
        ]
        self._token = declare_token(session, coord_alive_key(run, self.epoch, parent))  # after the subscribers: agents answer it
        others = {e: p for e, p in live_coordinators(session, run, own=self.epoch).items() if e != self.epoch}
        if others:  # two started at once: both may give up, never both go on (each checks after declaring)
            self.close()
            raise CoordinatorConflict(conflict_message(run, others))

    def resume(self, state: RunState) -> None:
        """Continue another coordinator's run from its checkpoint ``state``: at its global step, with its robots
        (the lost ones are not reported again), its estimate as the commands' start poses and, in simulation,
        the robots' last truths."""
        self.step = self._truths_sent = state.step
        self.config = state.config + 1 if state.plan is not None else state.config
        self.ids = state.estimate.ids.copy()
        self._id_list = self.ids.tolist()
        self._id_set = set(self._id_list)
        with self._lock:
            self._lost.update({x.robot: x.reason for x in state.result.lost if x.robot not in self._id_set})
        self._estimate = {robot: list(pose) for robot, pose in zip(self._id_list, state.estimate.poses.tolist(), strict=True)}
        last = state.result.steps[-1] if state.result.steps else None
        truth = state.result.initial_truth if last is None else last.truth
        if self.simulated and truth is not None:
            ids = state.result.initial_estimate.ids if last is None else last.estimate.ids
            self._truth.update({int(r): (state.step, np.array(pose, dtype=float)) for r, pose in zip(ids, truth, strict=True)})

    def publish_checkpoint(self, state: RunState) -> None:
        """Publish the executor's ``RunState`` after its step as a ``Checkpoint`` (``on_checkpoint`` of the executor)."""
        text, dropped = state.bounded_json(CHECKPOINT_STATE_CHARS)
        msg = Checkpoint(run=self.run, step=state.step, epoch=self.epoch, config=state.config + 1, group=state.group,
                         selector_calls=state.selector_calls, lost=tuple(sorted({x.robot for x in state.result.lost})),
                         state=text)
        if dropped and not self._dropped_warned:
            self._dropped_warned = True
            _log.warning("the checkpoint of step %d leaves out the estimate's %s (too large for a message): a takeover "
                         "from it is not bit for bit", state.step, ", ".join(dropped))
        publish(self.session, message_key(msg), encode(msg))

    # -- lost robots ------------------------------------------------------------------------

    def _on_liveliness(self, key: str, alive: bool) -> None:  # Zenoh thread
        try:
            robot = parse_key(key).robot
        except Exception:  # noqa: BLE001 - a key that is not a robot's token is not ours
            return
        if robot is None:  # not a robot's token either
            return
        with self._lock:
            if alive:
                self._alive.add(robot)
                if self._started and robot in self._lost and self.rejoin:
                    self._back.add(robot)
                return
            self._back.discard(robot)
            self._alive.discard(robot)
            started = self._started
        if started:
            self._stops.put((robot, None, time.monotonic()))  # the stopper thread asks the hub first

    def _on_coordinator(self, key: str, alive: bool) -> None:  # Zenoh thread
        """A coordinator whose parent is this epoch took the run over (this one stalled beyond its lease): step down.
        This coordinator's own token gone from its own view: its session lost the hub (its view is unsettled)."""
        token = parse_coord_token(key)
        if token is None:
            return
        if token[0] == self.epoch:
            self._own_alive = alive
            if not alive:
                self._link_lost_at = time.monotonic()
            return
        if alive:
            self._supersede({token[0]: token[1]})

    def _supersede(self, coordinators: dict[int, int]) -> bool:
        """Whether a coordinator among ``coordinators`` (``{epoch: parent}``, alive) took the run over from this one;
        if so this one steps down (any thread)."""
        taker = next((e for e, p in sorted(coordinators.items()) if p == self.epoch and e != self.epoch), None)
        if taker is not None and self.superseded is None:
            self.superseded = (f"coordinator epoch {taker} took run {self.run} over from this one (epoch {self.epoch}), "
                               f"which had lost its session to the hub; stepping down: no robot is declared lost, nothing is stopped")
        return self.superseded is not None

    def _on_estop(self, key: str, payload: bytes) -> None:  # Zenoh thread
        msg = decode_or_drop(payload, self.drops, key, EmergencyStop)
        if msg is not None and not msg.robots and self.stopped_by is None:
            self.stopped_by = f"the run was stopped by {msg.source} ({msg.reason})"

    def _connected(self) -> bool:
        """Whether the Zenoh link reaches the hub (a link that lost it sees every robot's token go with it: the robots
        are not to blame); a loss is noted, and once it lasts ``HUB_GRACE_S`` (not a stall this process is back from,
        whose session reconnects within milliseconds) the run ends with ``HubLost`` (any thread)."""
        info = self.session.info
        if list(info.routers_zid()) or list(info.peers_zid()):
            self._hub_gone_since = None
            return True
        with self._lock:
            self._link_lost_at = time.monotonic()
            if self._hub_gone_since is None:
                self._hub_gone_since = self._link_lost_at
        return False

    def _settled(self) -> bool:
        """Whether this process's view of the hub's tokens can be trusted: the session has the hub, has not lost it and
        this process has not stalled within ``RESYNC_S``, and this coordinator's own token is in its view again (a
        session that is back gets it with the hub's tokens, which the hub re-sends: until then its view is empty)."""
        connected = self._connected()  # (always asked: it notes how long the hub has been gone, HubLost after HUB_GRACE_S)
        return connected and self._own_alive and time.monotonic() - max(self._link_lost_at, self._stalled_at) >= RESYNC_S

    def _hub_view(self) -> tuple[set[int], dict[int, int]] | None:
        """The run's tokens at the hub (``live_run``): ``(robots alive, {epoch: parent} of the live coordinators})``,
        None without a complete answer."""
        view = live_run(self.session, self.run, own=self.epoch)
        return (set(view.robots), view.coordinators) if view.complete else None

    def _check_hub(self) -> None:
        """Raise ``HubLost`` once the hub has been gone for ``HUB_GRACE_S`` (caller's thread)."""
        since = self._hub_gone_since
        if since is None or time.monotonic() - since < HUB_GRACE_S or self._connected():
            return
        with self._lock:
            if self._hub_lost is None:
                self._hub_lost = (f"lost the connection to the hub after step {self.step}: no message, not even an emergency stop, "
                                  f"reaches the robots any more (each link stops feeding its robots, whose watchdogs stop them; "
                                  f"agents never move without a command)")
        raise HubLost(self._hub_lost)

    def _token_gone(self, robot: int, since: float) -> None:
        """Stopper thread: ``robot``'s token went from the Zenoh link's view at ``since`` (monotonic). Lost if the hub
        says so too, ``SETTLE_S`` later (a session closing on its hub drops every token before it drops the hub), and
        no coordinator took the run over from this one; while the view is unsettled (the session lost the hub, or
        this process stalled), a suspect judged once it has settled."""
        time.sleep(max(0.0, since + SETTLE_S - time.monotonic()))
        if self.stop_requested():  # gone with this process's own stop (a Ctrl-C to the whole run): not lost
            return
        if robot in self._alive:
            self._session_lost = True  # back already: it went with the Zenoh link to the hub, not with the robot
            return
        view = self._hub_view() if self._settled() else None
        if view is None or not self._settled():  # unsettled before or during the query: the hub's tokens may not be back
            self._session_lost = True
            self._suspect.add(robot)
            return
        alive, coordinators = view
        if self._supersede(coordinators):
            return
        if robot in alive or robot in self._alive:
            self._session_lost = True
            return
        self._declare_lost(robot, "liveliness token gone")

    def _check(self) -> None:
        """``SteppedDown`` once another coordinator holds the run, ``RunStopped`` once a run-wide stop was heard."""
        if self.superseded is not None:
            raise SteppedDown(self.superseded)
        if self.stopped_by is not None:
            raise RunStopped(self.stopped_by, [])

    def _recheck_suspects(self) -> None:
        """Stopper thread: once the view has settled, the hub is asked for the run's tokens: a coordinator that took the
        run over from this one makes it step down (no robot lost), else the suspects whose tokens are still gone are lost."""
        if not self._suspect or not self._settled():
            return
        view = self._hub_view()
        if view is None or not self._settled():
            return  # asked again at the next idle turn
        alive, coordinators = view
        if self._supersede(coordinators):
            self._suspect.clear()
            return
        gone = sorted(r for r in self._suspect if r not in alive and r not in self._alive)
        self._suspect.clear()
        for robot in gone:
            self._declare_lost(robot, "liveliness token gone")

    def _declare_lost(self, robot: int, reason: str, stop: bool = True) -> None:
        """Mark ``robot`` lost (once) and have the stopper thread send its emergency stop now (any thread); ``stop``
        False: it stands still already (its watchdog stopped it) and may come back at the next configuration."""
        if self.stop_requested():  # the run is being stopped as a whole: the run-wide stop covers every robot
            return
        with self._lock:
            if robot not in self.known or robot in self._lost or self.superseded is not None:
                return
            self._lost[robot] = reason
            self._untaken[robot] = reason
            if not stop and self.rejoin:
                self._back.add(robot)  # its agent serves on: re-admitted at the next configuration
        self._stops.put((robot, reason, float(stop)))

    def _note_stall(self, asked: float) -> None:
        """Stopper thread: its wait for the queue, begun at ``asked``, lasted ``STALL_S`` beyond its 0.2 s turn: this
        process stalled."""
        now = time.monotonic()
        if now - asked > 0.2 + STALL_S:
            self._stalled_at = now

    def _stop_lost(self) -> None:
        """Stopper thread: a targeted ``EmergencyStop`` and a ``RobotEvent`` for every lost robot, in order; the
        suspects of a lost session checked again meanwhile. A wait for the queue longer than ``STALL_S`` beyond its
        turn means this process stalled (its view of the hub's tokens is unsettled)."""
        while True:
            asked = time.monotonic()
            try:
                item = self._stops.get(timeout=0.2)
            except queue.Empty:
                self._note_stall(asked)
                self._recheck_suspects()
                continue
            self._note_stall(asked)
            if item is None:
                return
            robot, reason, stop_it = item
            if reason is None:
                self._token_gone(robot, float(stop_it))
                continue
            try:
                if stop_it:
                    stop = EmergencyStop(run=self.run, step=self.step, source="swarm coordinator", reason=f"robot lost: {reason}",
                                         robots=(robot,))
                    publish(self.session, message_key(stop), encode(stop))
                event = RobotEvent(run=self.run, step=self.step, robot=robot, kind="lost", reason=reason[:2000])
                publish(self.session, message_key(event), encode(event))
            except Exception:  # noqa: BLE001 - a closed session at shutdown: the launcher's run-wide stop covers it
                _log.exception("could not publish the emergency stop of lost robot %d", robot)
                continue
            _log.warning("robot %d lost (%s)%s", robot, reason, ": emergency stop sent" if stop_it else "")

    def take_lost(self) -> dict[int, str]:
        """The robots lost since the last call, with why; they leave ``ids``. ``HubLost`` once the hub is gone."""
        self._check_hub()
        with self._lock:
            taken, self._untaken = self._untaken, {}
        if taken:
            self.ids = self.ids[~np.isin(self.ids, list(taken))]
            self._id_list = self.ids.tolist()
            self._id_set = set(self._id_list)
        return taken

    def lose(self, robot: int, reason: str) -> None:
        """Declare ``robot`` lost (its stop and event are sent; ``take_lost`` reports it)."""
        self._declare_lost(robot, reason)

    def take_rejoining(self) -> list[int]:
        """Lost robots whose agents came back since the last call (their tokens alive again)."""
        with self._lock:
            back, self._back = sorted(self._back & self._alive), set()
        return back

    def observe_rejoining(self, robots: list[int]) -> Observations:
        """Bring ``robots`` (lost, their agents back) into the run: each is asked for its observations of the
        current step (a simulated one first gets the step's truth set, with its own truth); those that answer are
        in ``ids`` again and get a ``RobotEvent`` rejoined, the others are lost again. Their reports."""
        s = self.step
        with self._lock:
            for robot in robots:
                self._lost.pop(robot, None)
        self.ids = np.array(sorted({*self._id_list, *robots}), dtype=np.int64)
        self._id_list = self.ids.tolist()
        self._id_set = set(self._id_list)
        self._truths_sent = s - 1  # the set is sent again, with their truths
        self._observe_round(robots, f"the observation request of step {s} (rejoining)")
        joined = [r for r in robots if r in self._reports and r not in self._lost]
        for robot in joined:
            event = RobotEvent(run=self.run, step=s, robot=robot, kind="rejoined", reason="its agent came back")
            publish(self.session, message_key(event), encode(event))
            _log.warning("robot %d rejoined the run after step %d", robot, s)
        return observations_from_reports(self._reports[r] for r in joined)

    def _present(self) -> list[int]:
        """Robots of ``ids`` not lost meanwhile."""
        with self._lock:
            return [r for r in self._id_list if r not in self._lost]

    # -- inbox (caller's thread) --------------------------------------------------------

    def _pump(self, timeout_s: float) -> None:
        """Handle queued messages for up to ``timeout_s`` (returns after the first batch; 0: only what is queued);
        ``HubLost`` once the hub is gone."""
        self._check_hub()
        try:
            key, payload = self._inbox.get(timeout=timeout_s) if timeout_s > 0 else self._inbox.get_nowait()
        except queue.Empty:
            return
        while True:
            if key:
                self._handle(key, payload)
            else:
                self._check_hub()
            try:
                key, payload = self._inbox.get_nowait()
            except queue.Empty:
                return

    def _foreign(self, key: str, problem: str) -> None:
        self.drops.drop(key, MessageError("message", problem, "foreign"))

    def _handle(self, key: str, payload: bytes) -> None:
        msg = decode_or_drop(payload, self.drops, key, None, self.known)
        if msg is None:
            return
        if isinstance(msg, TruthMessage) and self.step == 0 and msg.robot in self._id_set:
            # before the first step a robot's current truth is the run's start, whatever step its publisher counts
            # (a motion-capture publisher, e.g. the emulator, keeps counting across runs)
            self._truth[msg.robot] = (0, np.array(msg.pose, dtype=float))
            return
        if not isinstance(msg, (TruthMessage, ObservationReport, Status)):
            return  # the keys subscribed carry nothing else (decode checks the type against the key)
        if msg.step != self.step:
            if msg.step > self.step:  # late answers to earlier steps are normal (re-sends); later steps are not
                self._foreign(key, f"{msg.TYPE} for step {msg.step}, the run is at step {self.step}")
            return
        if msg.robot not in self._id_set:
            self._foreign(key, f"{msg.TYPE} from robot {msg.robot}, which is not in the run")
            return
        if isinstance(msg, TruthMessage):
            self._truth[msg.robot] = (msg.step, np.array(msg.pose, dtype=float))
            self._truth_now.add(msg.robot)
            if msg.robot in self._reports:
                self._owed_obs.discard(msg.robot)
            self._publish_truth_set()
        elif isinstance(msg, ObservationReport):
            self._reports[msg.robot] = msg
            if not self.simulated or msg.robot in self._truth_now:
                self._owed_obs.discard(msg.robot)
        elif isinstance(msg, Status):
            cmd = self._cmds.get(msg.robot)
            if cmd is None or msg.cmd_id != cmd.cmd_id:
                self._foreign(key, f"Status of robot {msg.robot} for step {msg.step} answers no command of this coordinator")
                return
            old = self._status.get(msg.robot)
            if old is None or old.state == "accepted":
                self._status[msg.robot] = msg
            if msg.state == "done":
                self._owed_done.discard(msg.robot)
            elif msg.state == "refused" and OTHER_MASTER.search(msg.reason):
                self.superseded = self.superseded or (f"robot {msg.robot} refused the command of step {msg.step}: {msg.reason}; "
                                                      "stepping down: no robot is declared lost, nothing is stopped")
            elif msg.state == "refused" and msg.reason.startswith(RUN_STOPPED_REFUSAL):  # the run's e-stop reached
                self.stopped_by = self.stopped_by or msg.reason.replace(RUN_STOPPED_REFUSAL, "the run was stopped", 1)  # it first
            elif msg.state == "refused":
                self._declare_lost(msg.robot, f"refused the command of step {msg.step}: {msg.reason}",
                                   stop=WATCHDOG_REFUSAL not in msg.reason)

    def _publish_truth_set(self, again: bool = False) -> None:
        """Simulation: once every present robot's truth of the current step is in, send them to the agents as
        one ``TruthSetMessage`` (n messages per step instead of n^2); ``again`` re-sends it (a resend round)."""
        s = self.step
        if not self.simulated or s == 0 or s > self._asked or (s <= self._truths_sent and not again):
            return  # (the moving agents' truths come with their Status done: the set waits for the requests)
        if len(self._truth_now) < len(self._id_list) - len(self._lost):  # O(1) until the set can be complete
            return
        present = self._present()
        if not present or not self._truth_now.issuperset(present):
            return
        msg = TruthSetMessage(run=self.run, step=s, ids=tuple(present), poses=tuple(tuple(self._truth[r][1].tolist()) for r in present),
                              epoch=self.epoch)
        publish(self.session, message_key(msg), encode(msg))
        self._truths_sent = s

    def _wait(self, what: str, missing: Callable[[], list[int]], resend: Callable[[list[int]], None]) -> None:
        """Pump until ``missing()`` (robots still owing an answer, lost ones excluded) is empty; re-send once at half
        the timeout; at the timeout the robots still missing are lost. While this coordinator's view is unsettled
        (``_settled``: this process stalled, a turn of this loop longer than ``STALL_S`` included, or its session lost
        the hub) no time counts: answers may still be in its socket, and those sent while its session was gone are
        lost; once it has settled the requests are re-sent and the robots have half the timeout to answer them."""
        start = last = time.monotonic()
        resent = False
        while True:
            now = time.monotonic()
            if now - last > STALL_S:
                self._stalled_at = now
            last = now
            self._check()
            self._publish_truth_set()  # a robot lost meanwhile may complete the set
            left = missing()
            if not left:
                return
            if not self._settled():  # no robot is to blame yet (without the hub: back soon, or HubLost after HUB_GRACE_S)
                start, resent = now - self.timeouts.step_s / 2, False
                self._pump(0.05)
                continue
            elapsed = now - start
            if elapsed > self.timeouts.step_s:
                self._pump(0.0)  # answers already received count, however late this thread looks at them (a stall)
                self._publish_truth_set()
                left = missing()
                with self._lock:
                    alive = [r for r in left if r in self._alive]
                if self._session_lost and alive and self.superseded is None:  # they serve another coordinator, not us
                    self.superseded = (f"{_robots(alive)} alive but silent to this coordinator (epoch {self.epoch}) since it lost "
                                       f"its session to the hub: another coordinator has held run {self.run}; stepping down: "
                                       "no robot is declared lost, nothing is stopped")
                    self._check()
                for robot in left:
                    self._declare_lost(robot, f"did not answer {what} within {self.timeouts.step_s:.1f} s")
                return
            if not resent and elapsed >= self.timeouts.step_s / 2:
                resend(left)
                resent = True
            self._pump(0.05)

    # -- start --------------------------------------------------------------------------

    def wait_for_agents(self, timeout_s: float | None = None) -> None:
        """Until every robot's token is alive (and, simulated, its initial truth is known)."""
        timeout_s = self.timeouts.start_s if timeout_s is None else timeout_s
        deadline = time.monotonic() + timeout_s
        while True:
            with self._lock:
                missing = sorted(self._id_set - self._alive)
            no_truth = sorted(self._id_set - self._truth.keys()) if self.simulated else []
            if not missing and not no_truth:
                with self._lock:
                    self._started = True
                    gone = sorted(self._id_set - self._alive)  # a token withdrawn since the check above
                for robot in gone:
                    self._declare_lost(robot, "liveliness token gone")
                return
            if time.monotonic() > deadline:
                if missing:
                    raise AgentLost(f"{_robots(missing)} not alive after {timeout_s:.1f} s (an agent that failed to start says why on its "
                                    f"own stderr; one that runs may have another run id or hub)",
                                    missing)
                raise AgentLost(f"no initial true pose from {_robots(no_truth)} after {timeout_s:.1f} s", no_truth)
            self._pump(0.05)

    # -- SwarmBackend -------------------------------------------------------------------

    def execute(self, step: StepCommands) -> None:
        if not np.array_equal(step.ids, self.ids):
            raise SwarmInputError(f"commands for robots {step.ids.tolist()}, swarm has {self._id_list}")
        self._check()  # never a command once another coordinator holds the run or it was stopped
        self.step += 1
        s = self.step
        self._status = {}
        self._truth_now = set()
        present = set(self._present())
        self._cmds = {}
        for k in np.flatnonzero(step.moving):
            robot = self._id_list[k]
            if robot not in present:
                continue  # lost meanwhile: never command it again
            turn, drive = step.commands[k]
            start = () if self._estimate is None else tuple(self._estimate.get(robot, ()))
            self._cmds[robot] = MotionCommand(run=self.run, step=s, robot=robot, config=self.config, turn_rad=float(turn),
                                              drive_m=float(drive), start_pose=start, cmd_id=secrets.randbits(63) or 1,
                                              epoch=self.epoch)
        cmds = self._cmds

        def send(robots: Iterable[int]) -> None:
            for robot in robots:
                publish(self.session, message_key(cmds[robot]), encode(cmds[robot]))

        def missing() -> list[int]:
            with self._lock:
                return sorted(self._owed_done.difference(self._lost))

        self._owed_done = set(cmds)
        send(cmds)
        self._wait(f"the command of step {s}", missing, send)

    def observe(self) -> Observations:
        self._observe_round(self._present(), f"the observation request of step {self.step}")
        return observations_from_reports(self._reports[r] for r in self._present() if r in self._reports)

    def _observe_round(self, robots: list[int], what: str) -> None:
        """``ObserveRequest`` (the current step) to ``robots``, then wait for their reports (and truths) in
        ``self._reports``; the step's truth set goes out once complete, never before the requests, and again
        with every re-send (an agent may have missed it)."""
        self._check()
        s = self.step
        self._reports = {}
        requests = {r: ObserveRequest(run=self.run, step=s, robot=r, epoch=self.epoch) for r in robots}

        def send(targets: Iterable[int]) -> None:
            for robot in targets:
                publish(self.session, message_key(requests[robot]), encode(requests[robot]))
            self._publish_truth_set(again=True)

        def missing() -> list[int]:
            with self._lock:
                return sorted(self._owed_obs.difference(self._lost))

        self._owed_obs = set(requests)
        self._asked = s
        send(list(requests))
        self._wait(what, missing, send)

    # -- ExecutorListener ---------------------------------------------------------------

    def on_plan(self, config_index: int, first_step: int, plan: Plan, selection: Selection | None) -> None:
        """Publish the plan of configuration ``config_index`` (0-based) as ``PlanMessage`` (``config`` 1-based)."""
        self.config = config_index + 1
        groups = tuple(tuple(self._id_list[int(k)] for k in group) for group in plan.groups)
        msg = PlanMessage(run=self.run, step=first_step, config=self.config, n_anchors=plan.n_anchors, groups=groups)
        publish(self.session, message_key(msg), encode(msg))

    def on_leg(self, config_index: int, leg: int, first_step: int, record: LegRecord) -> None:
        """Publish approach leg ``leg`` (>= 1) of configuration ``config_index`` (0-based) as ``PlanMessage`` (``leg`` set)."""
        groups = tuple(tuple(int(record.ids[k]) for k in group) for group in record.plan.groups)
        msg = PlanMessage(run=self.run, step=first_step, config=config_index + 1, n_anchors=record.n_anchors(len(self.ids)),
                          groups=groups, leg=leg)
        publish(self.session, message_key(msg), encode(msg))

    def on_estimate(self, step: int, estimate: SwarmEstimate) -> None:
        """Publish the estimate after ``step`` as ``EstimateMessage``."""
        msg = EstimateMessage.from_estimate(estimate, run=self.run, step=step)
        publish(self.session, message_key(msg), encode(msg))
        self._estimate = {robot: list(pose) for robot, pose in zip(msg.ids, msg.poses, strict=True)}

    def on_contacts(self, contacts: list[ContactEvent]) -> None:
        """Publish each contact of the robots' true bodies (``ContactEvent``) as ``ContactMessage``."""
        for c in contacts:
            msg = ContactMessage(run=self.run, step=c.step, config=c.config + 1, a=c.a, b=c.b, distance_m=c.distance,
                                 radius_m=self.radius, point=c.point)
            publish(self.session, message_key(msg), encode(msg))

    def true_poses(self) -> np.ndarray | None:
        if not self.simulated or not self._id_set <= self._truth.keys():
            return None
        return np.array([self._truth[r][1] for r in self._id_list])

    def close(self) -> None:
        """Stop serving: the stopper thread finishes the stops it holds, then tokens and subscribers go."""
        self._stops.put(None)
        self._stopper.join(timeout=5.0)
        self._token.undeclare()
        for sub in self._subs:
            sub.undeclare()
