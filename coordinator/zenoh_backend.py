"""The distributed swarm backend: the executor's ``SwarmBackend`` over Zenoh (docs/protocol.md).

``ZenohSwarmBackend`` talks to one agent process per robot through an open session:

* ``execute(step)``: the next global step number s (motion steps from 1);
  ``MotionCommand`` (step s) to each moving robot, then waits until every one of them
  answered ``Status done``. A ``refused`` answer raises ``AgentRefused`` naming the robot
  and its reason (the executor's dead reckoning assumes the robot moved).
* ``observe()``: ``ObserveRequest`` (step s) to every robot; waits for every robot's
  ``ObservationReport`` of step s (and, for simulated agents, its ``TruthMessage``) and
  returns the observations in the order of ``ids`` (the in-process simulator's order).
* ``true_poses()``: the latest truths of all robots (simulation), or None.

It is also the executor's ``ExecutorListener`` (pass it as ``listener=``):
``on_plan`` publishes ``PlanMessage`` on ``swarm/<run>/coord/plan`` (``config`` 1-based,
``step`` the plan's first step, groups as robot ids) and makes the following
``MotionCommand``s carry that ``config``; ``on_estimate`` publishes ``EstimateMessage``
on ``swarm/<run>/coord/estimate`` (step 0: the initial estimate, then after every step)
and makes the following commands carry the robot's estimated pose as ``start_pose``.
Without a listener call the commands carry ``config`` 0.

Lost agents: a liveliness subscriber on ``swarm/<run>/alive/robot/*`` notes every token
that disappears; every wait checks it each 50 ms and raises ``AgentLost``
("robot 3 lost (liveliness token gone)"); a robot that does not answer within
``timeouts.step_s`` raises ``AgentLost`` ("robot 3 did not answer the command of step 12 within 5.0 s").
Each command or request is re-sent once at half the timeout (agents are idempotent).
All Zenoh callbacks only enqueue or set flags; the waiting happens on the caller's thread.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections.abc import Collection
from dataclasses import dataclass

import numpy as np

from runtime.errors import SwarmInputError
from runtime.keys import alive_wildcard, coord_alive_key, parse_key, robot_wildcard, truth_wildcard
from runtime.messages import (
    DropCounter,
    EstimateMessage,
    MotionCommand,
    ObservationReport,
    ObserveRequest,
    PlanMessage,
    Status,
    TruthMessage,
    TruthSetMessage,
    decode_or_drop,
    encode,
    message_key,
    observations_from_reports,
)
from runtime.state import Observations, StepCommands, SwarmEstimate
from runtime.transport import declare_token, publish, subscribe, watch_liveliness

_log = logging.getLogger(__name__)


class AgentError(SwarmInputError):
    """A robot agent failed the run; ``robots`` names the robot ids."""

    def __init__(self, message: str, robots: list[int]) -> None:
        super().__init__(message)
        self.robots = robots


class AgentLost(AgentError):
    """Agents whose liveliness token disappeared or that did not answer in time."""


class AgentRefused(AgentError):
    """An agent refused its command."""


@dataclass(frozen=True)
class Timeouts:
    """Seconds to wait: for the agents at start, and for every answer of a step."""

    start_s: float = 30.0
    step_s: float = 5.0


def _robots(ids: list[int]) -> str:
    return f"robot {ids[0]}" if len(ids) == 1 else f"robots {', '.join(map(str, ids))}"


class ZenohSwarmBackend:
    """``SwarmBackend`` of the agents of run ``run`` with robots ``ids``, over ``session``."""

    def __init__(self, session, run: str, ids: Collection[int], timeouts: Timeouts = Timeouts(), simulated: bool = True) -> None:
        self.session = session
        self.run = run
        self.ids = np.array(sorted(int(i) for i in ids), dtype=np.int64)
        self._id_list = self.ids.tolist()
        self.known = frozenset(self._id_list)
        self.timeouts = timeouts
        self.simulated = simulated
        self.step = 0  # last global step number used
        self.config = 0  # 1-based configuration of the current plan (0 before on_plan)
        self.drops = DropCounter(_log)
        self._inbox: queue.Queue[tuple[str, bytes]] = queue.Queue()
        self._lock = threading.Lock()
        self._alive: set[int] = set()
        self._gone: set[int] = set()
        self._truth: dict[int, tuple[int, np.ndarray]] = {}
        self._truths_sent = 0  # last step whose TruthSetMessage went out
        self._estimate: dict[int, list[float]] | None = None  # latest published pose per robot: commands' start_pose
        self._reports: dict[int, ObservationReport] = {}
        self._status: dict[int, Status] = {}
        enqueue = lambda key, payload: self._inbox.put((key, payload))  # noqa: E731 (Zenoh thread: enqueue only)
        self._subs = [
            subscribe(session, robot_wildcard(run, "status"), enqueue),
            subscribe(session, robot_wildcard(run, "obs"), enqueue),
            subscribe(session, truth_wildcard(run), enqueue),
            watch_liveliness(session, alive_wildcard(run), self._on_liveliness),
        ]
        self._token = declare_token(session, coord_alive_key(run))  # after the subscribers: agents answer it with truths

    # -- liveliness (Zenoh thread) ------------------------------------------------------

    def _on_liveliness(self, key: str, alive: bool) -> None:
        try:
            robot = parse_key(key).robot
        except Exception:
            return
        with self._lock:
            if alive:
                self._alive.add(robot)
                self._gone.discard(robot)
            else:
                self._alive.discard(robot)
                if robot in self.known:
                    self._gone.add(robot)

    def lost(self) -> list[int]:
        with self._lock:
            return sorted(self._gone)

    def _check_lost(self) -> None:
        gone = self.lost()
        if gone:
            raise AgentLost(f"{_robots(gone)} lost (liveliness token gone)", gone)

    # -- inbox (caller's thread) --------------------------------------------------------

    def _pump(self, timeout_s: float) -> None:
        """Handle queued messages for up to ``timeout_s`` (returns after the first batch)."""
        try:
            key, payload = self._inbox.get(timeout=timeout_s)
        except queue.Empty:
            return
        while True:
            self._handle(key, payload)
            try:
                key, payload = self._inbox.get_nowait()
            except queue.Empty:
                return

    def _handle(self, key: str, payload: bytes) -> None:
        msg = decode_or_drop(payload, self.drops, key, None, self.known)
        if msg is None:
            return
        if isinstance(msg, TruthMessage):
            old = self._truth.get(msg.robot)
            if old is None or msg.step >= old[0]:
                self._truth[msg.robot] = (msg.step, np.array(msg.pose, dtype=float))
            self._publish_truth_set()
        elif msg.step != self.step:
            return  # an answer to another step (late duplicate or foreign): not ours to use
        elif isinstance(msg, ObservationReport):
            self._reports[msg.robot] = msg
        elif isinstance(msg, Status):
            old = self._status.get(msg.robot)
            if old is None or old.state == "accepted":
                self._status[msg.robot] = msg

    def _publish_truth_set(self, again: bool = False) -> None:
        """Simulation: once every robot's truth of the current step is in, send them to the agents as one
        ``TruthSetMessage`` (n messages per step instead of n^2); ``again`` re-sends it (a resend round)."""
        s = self.step
        if not self.simulated or s == 0 or (s <= self._truths_sent and not again):
            return
        if not self.known <= self._truth.keys() or any(self._truth[r][0] < s for r in self._id_list):
            return
        msg = TruthSetMessage(run=self.run, step=s, ids=self._id_list, poses=[self._truth[r][1] for r in self._id_list])
        publish(self.session, message_key(msg), encode(msg))
        self._truths_sent = s

    def _wait(self, what: str, missing, resend) -> None:
        """Pump until ``missing()`` is empty; re-send once at half the timeout; raise on loss or timeout."""
        start = time.monotonic()
        resent = False
        while True:
            self._check_lost()
            left = missing()
            if not left:
                return
            elapsed = time.monotonic() - start
            if elapsed > self.timeouts.step_s:
                raise AgentLost(f"{_robots(left)} did not answer {what} within {self.timeouts.step_s:.1f} s", left)
            if not resent and elapsed > self.timeouts.step_s / 2:
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
                missing = sorted(self.known - self._alive)
                self._gone.clear()  # an agent restarting before the run starts is fine
            no_truth = sorted(self.known - self._truth.keys()) if self.simulated else []
            if not missing and not no_truth:
                return
            if time.monotonic() > deadline:
                if missing:
                    raise AgentLost(f"{_robots(missing)} not alive after {timeout_s:.1f} s (is every agent started with this run id and hub?)", missing)
                raise AgentLost(f"no initial true pose from {_robots(no_truth)} after {timeout_s:.1f} s", no_truth)
            self._pump(0.05)

    # -- SwarmBackend -------------------------------------------------------------------

    def execute(self, step: StepCommands) -> None:
        if not np.array_equal(step.ids, self.ids):
            raise SwarmInputError(f"commands for robots {step.ids.tolist()}, swarm has {self._id_list}")
        self.step += 1
        s = self.step
        self._status = {}
        cmds = {}
        for k in np.flatnonzero(step.moving):
            robot = self._id_list[k]
            turn, drive = step.commands[k]
            start = () if self._estimate is None else self._estimate.get(robot, ())
            cmds[robot] = MotionCommand(run=self.run, step=s, robot=robot, config=self.config, turn_rad=float(turn),
                                        drive_m=float(drive), start_pose=start)

        def send(robots) -> None:
            for robot in robots:
                publish(self.session, message_key(cmds[robot]), encode(cmds[robot]))

        def missing() -> list[int]:
            refused = sorted(r for r, st in self._status.items() if st.state == "refused")
            if refused:
                reasons = "; ".join(f"robot {r}: {self._status[r].reason}" for r in refused)
                raise AgentRefused(f"{_robots(refused)} refused the command of step {s} ({reasons})", refused)
            return sorted(r for r in cmds if r not in self._status or self._status[r].state != "done")

        send(cmds)
        self._wait(f"the command of step {s}", missing, send)

    def observe(self) -> Observations:
        s = self.step
        self._reports = {}
        requests = {r: ObserveRequest(run=self.run, step=s, robot=r) for r in self._id_list}

        def send(robots) -> None:
            for robot in robots:
                publish(self.session, message_key(requests[robot]), encode(requests[robot]))
            self._publish_truth_set(again=True)  # a resend round: agents may have missed it

        def missing() -> list[int]:
            left = [r for r in self._id_list if r not in self._reports]
            if self.simulated:
                left += [r for r in self._id_list if r not in left and (r not in self._truth or self._truth[r][0] < s)]
            return sorted(left)

        send(self._id_list)
        self._wait(f"the observation request of step {s}", missing, send)
        return observations_from_reports(self._reports[r] for r in self._id_list)

    # -- ExecutorListener ---------------------------------------------------------------

    def on_plan(self, config_index: int, first_step: int, plan, selection) -> None:
        """Publish the plan of configuration ``config_index`` (0-based) as ``PlanMessage`` (``config`` 1-based)."""
        self.config = config_index + 1
        groups = [[self._id_list[int(k)] for k in group] for group in plan.groups]
        msg = PlanMessage(run=self.run, step=first_step, config=self.config, n_anchors=plan.n_anchors, groups=groups)
        publish(self.session, message_key(msg), encode(msg))

    def on_estimate(self, step: int, estimate: SwarmEstimate) -> None:
        """Publish the estimate after ``step`` as ``EstimateMessage``."""
        msg = EstimateMessage.from_estimate(estimate, run=self.run, step=step)
        publish(self.session, message_key(msg), encode(msg))
        self._estimate = {robot: list(pose) for robot, pose in zip(msg.ids, msg.poses)}

    def true_poses(self) -> np.ndarray | None:
        if not self.simulated or not self.known <= self._truth.keys():
            return None
        return np.array([self._truth[r][1] for r in self._id_list])

    def close(self) -> None:
        self._token.undeclare()
        for sub in self._subs:
            sub.undeclare()
