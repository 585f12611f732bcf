"""The merged truth round (docs/protocol.md, Step sequence) on a real loopback Zenoh hub.

A simulated agent publishes its step's truth right after its ``Status done`` and not again for the
step's first ``ObserveRequest``; a truth set that reaches it before its request is kept until the
request comes; the coordinator never publishes a step's truth set before that step's requests.
"""

from __future__ import annotations

import contextlib
import queue
import threading
import time
from collections.abc import Iterator

import numpy as np
import pytest
import zenoh

from coordinator.node.zenoh_backend import RunStopped, Timeouts, ZenohSwarmBackend
from robot_agent.agent import Agent
from robot_agent.driver import SimDriver
from runtime.models.config import ModelConfig
from runtime.models.state import StepCommands
from runtime.wire.keys import alive_wildcard, estop_key, robot_key, robot_wildcard, run_wildcard, truths_key
from runtime.wire.messages import (
    RUN_STOPPED_REFUSAL,
    EmergencyStop,
    MotionCommand,
    ObservationReport,
    ObserveRequest,
    Status,
    TruthMessage,
    TruthSetMessage,
    decode,
    encode,
)
from runtime.wire.transport import alive_now, open_loopback_hub, open_session, publish, subscribe, subscribe_queue
from tests.agent_hub import agent_on_hub
from tests.waiting import wait_for

RUN = "truth-round"
EPOCH = 23  # the test acts as the coordinator of this epoch
ROBOT_POSES = {0: (0.0, 0.0, 0.0), 1: (0.2, 0.0, 0.0)}


def _wait_alive(session, count: int) -> None:
    deadline = time.monotonic() + 10
    while len(alive_now(session, alive_wildcard(RUN))) < count:
        assert time.monotonic() < deadline, "agents did not come up"
        time.sleep(0.02)


@pytest.fixture
def agent_and_run():
    """Robot 0's agent (simulated) on a hub; everything published on the run, decoded, in a queue."""
    with agent_on_hub(RUN, EPOCH, np.array(ROBOT_POSES[0]), run_wildcard(RUN)) as running:
        yield running


def _agent_messages(seen: queue.Queue, until: type, timeout_s: float = 5.0) -> list:
    """The agent's decoded messages (truths, statuses, reports) up to the first of type ``until``."""
    got = []
    deadline = time.monotonic() + timeout_s
    while True:
        key, payload = seen.get(timeout=max(0.01, deadline - time.monotonic()))
        msg = decode(payload)
        if isinstance(msg, (TruthMessage, Status, ObservationReport)) and msg.step > 0:
            got.append(msg)
            if isinstance(msg, until):
                return got


def _published_by_agent(seen: queue.Queue) -> list:
    """What the agent published (truths, statuses, reports) among the samples queued so far."""
    got = []
    while not seen.empty():
        msg = decode(seen.get()[1])
        if isinstance(msg, (TruthMessage, Status, ObservationReport)) and msg.step > 0:
            got.append(msg)
    return got


def _truth_set(step: int, pose0) -> TruthSetMessage:
    return TruthSetMessage(run=RUN, step=step, ids=(0, 1), poses=(tuple(pose0), ROBOT_POSES[1]), epoch=EPOCH)


def test_a_moving_agent_sends_its_truth_with_done_and_not_again_for_the_first_request(agent_and_run):
    hub, agent, seen = agent_and_run
    publish(hub, robot_key(RUN, 0, "cmd"), encode(MotionCommand(run=RUN, step=1, robot=0, config=1, turn_rad=0.1, drive_m=0.05,
                                                                cmd_id=7, epoch=EPOCH)))
    got = _agent_messages(seen, TruthMessage)
    assert [(type(m).__name__, getattr(m, "state", "")) for m in got] == [("Status", "done"), ("TruthMessage", "")]
    truth = got[-1]
    assert truth.step == 1 and truth.pose != ROBOT_POSES[0]  # the pose after the motion
    publish(hub, robot_key(RUN, 0, "observe"), encode(ObserveRequest(run=RUN, step=1, robot=0, epoch=EPOCH)))
    time.sleep(0.3)
    publish(hub, truths_key(RUN), encode(_truth_set(1, truth.pose)))
    got = _agent_messages(seen, ObservationReport)
    assert [type(m) for m in got] == [ObservationReport]  # no second truth for the first request
    report = got[0]
    assert report.step == 1 and report.observed == (1,)
    publish(hub, robot_key(RUN, 0, "observe"), encode(ObserveRequest(run=RUN, step=1, robot=0, epoch=EPOCH)))  # a re-send
    got = _agent_messages(seen, ObservationReport)
    assert [type(m) for m in got] == [TruthMessage, ObservationReport]  # the truth again, with the same report
    assert got[0].pose == truth.pose and (got[1].observed, got[1].ranges, got[1].bearings) == (report.observed, report.ranges, report.bearings)


def test_a_truth_set_that_overtakes_its_request_is_kept_until_the_request_comes(agent_and_run):
    hub, agent, seen = agent_and_run
    publish(hub, robot_key(RUN, 0, "cmd"), encode(MotionCommand(run=RUN, step=1, robot=0, config=1, turn_rad=0.0, drive_m=0.05,
                                                                cmd_id=9, epoch=EPOCH)))
    truth = _agent_messages(seen, TruthMessage)[-1]
    publish(hub, truths_key(RUN), encode(_truth_set(1, truth.pose)))  # before the request
    time.sleep(0.3)
    assert _published_by_agent(seen) == [] and agent.drops.total == 0  # kept, not dropped, and no report without a request
    publish(hub, robot_key(RUN, 0, "observe"), encode(ObserveRequest(run=RUN, step=1, robot=0, epoch=EPOCH)))
    got = _agent_messages(seen, ObservationReport)
    assert [type(m) for m in got] == [ObservationReport] and got[0].observed == (1,)


def test_a_truth_set_for_a_step_the_agent_has_no_truth_of_is_still_dropped(agent_and_run):
    hub, agent, seen = agent_and_run
    publish(hub, truths_key(RUN), encode(_truth_set(1, ROBOT_POSES[0])))  # no command, no request: nothing to keep it for
    deadline = time.monotonic() + 3
    while agent.drops.total < 1 and time.monotonic() < deadline:
        time.sleep(0.02)
    assert agent.drops.total == 1
    publish(hub, robot_key(RUN, 0, "observe"), encode(ObserveRequest(run=RUN, step=1, robot=0, epoch=EPOCH)))
    got = _agent_messages(seen, TruthMessage)  # an anchor: its truth comes on the request ...
    time.sleep(0.3)
    assert [type(m) for m in got] == [TruthMessage] and _published_by_agent(seen) == []  # ... and it waits for a real set


@contextlib.contextmanager
def two_agents() -> Iterator[tuple[zenoh.Session, zenoh.Session, list[Agent]]]:
    """A loopback hub, the coordinator's session and robots 0 and 1's simulated agents running on threads (stopped
    at the end)."""
    hub, member, _ = open_loopback_hub()
    with hub, open_session(member) as coordinator_session:
        agents = [Agent(member, RUN, r, [0, 1], SimDriver(r, [0, 1], np.array(ROBOT_POSES[r]), ModelConfig(), seed=3)) for r in (0, 1)]
        threads = [threading.Thread(target=a.run, daemon=True) for a in agents]
        for t in threads:
            t.start()
        try:
            _wait_alive(hub, 2)
            yield hub, coordinator_session, agents
        finally:
            for a in agents:
                a.stop()
            for t in threads:
                t.join(timeout=5)


def test_the_coordinator_sends_a_steps_truth_set_only_after_its_requests():
    with two_agents() as (hub, coordinator_session, agents):
        _, seen = subscribe_queue(hub, run_wildcard(RUN))
        backend = ZenohSwarmBackend(coordinator_session, RUN, [0, 1], Timeouts(10.0, 4.0))
        try:
            backend.wait_for_agents()
            for _ in range(2):
                backend.execute(StepCommands(backend.ids, np.array([[0.1, 0.05], [0.0, 0.05]]), np.array([True, True])))
                time.sleep(0.3)  # every truth of the step is in: still no truth set before the requests
                observations = backend.observe()
                assert len(observations.observer) == 2  # each sees the other
        finally:
            backend.close()
        stamped = []  # by publish time (one wall clock): Zenoh does not keep the order of different keys
        while not seen.empty():
            msg = decode(seen.get()[1])
            if isinstance(msg, (ObserveRequest, TruthSetMessage, TruthMessage)) and msg.step > 0:
                stamped.append((msg.stamp_ns, msg.step, type(msg).__name__))
        for step in (1, 2):
            kinds = [k for _, s, k in sorted(stamped) if s == step]
            assert kinds.count("TruthSetMessage") == 1 and kinds.count("ObserveRequest") == 2 and kinds.count("TruthMessage") == 2
            assert kinds[:2] == ["TruthMessage", "TruthMessage"]  # with done, during the command round
            assert kinds[-1] == "TruthSetMessage"  # after both requests
        assert backend.drops.total == 0 and all(a.drops.total == 0 for a in agents)


def test_a_refusal_for_the_runs_emergency_stop_ends_the_run_as_stopped_and_loses_no_robot():
    """The launcher's run-wide stop reaches the agents before the coordinator (Zenoh keeps no order across keys):
    the agents refuse the next command for it, and the coordinator ends the run as stopped by whoever stopped it,
    declaring no robot lost."""
    with two_agents() as (hub, coordinator_session, agents):
        publish(hub, estop_key(RUN), encode(EmergencyStop(run=RUN, step=0, source="swarm launch (pid 7)", reason="interrupted")))
        deadline = time.monotonic() + 5
        while not all(a.estopped for a in agents):
            assert time.monotonic() < deadline, "the agents did not hear the stop"
            time.sleep(0.02)
        # on the coordinator's session, before its backend subscribes: whatever status reaches the backend reaches this too
        statuses: list[Status] = []
        _sub = subscribe(coordinator_session, robot_wildcard(RUN, "status"), lambda key, payload: statuses.append(decode(payload, Status)))
        backend = ZenohSwarmBackend(coordinator_session, RUN, [0, 1], Timeouts(10.0, 4.0))  # subscribes after the stop
        try:
            backend.wait_for_agents()
            with pytest.raises(RunStopped, match=r"^the run was stopped by swarm launch \(pid 7\) \(interrupted\)$"):
                for _ in range(3):
                    backend.execute(StepCommands(backend.ids, np.array([[0.1, 0.05], [0.0, 0.05]]), np.array([True, True])))
                    backend.observe()
            assert backend.take_lost() == {}
        finally:
            backend.close()
        # the refusal that ended the run, as the agent said it; no robot moved. (The robot whose refusal came second may
        # have refused for the coordinator's epoch instead: its token went when the run ended, and overtook the command.)
        said = f"{RUN_STOPPED_REFUSAL} by swarm launch (pid 7) (interrupted)"
        wait_for(lambda: any(s.reason == said for s in statuses), 10, "the agents' refusal for the run's stop")
        assert all(s.state == "refused" for s in statuses), statuses
