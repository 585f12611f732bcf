"""One robot agent on a real loopback Zenoh hub: refusals, idempotency, bad input (in-process thread)."""

from __future__ import annotations

import queue
import time

import numpy as np
import pytest

from runtime.wire.keys import estop_key, robot_key
from runtime.wire.messages import RUN_STOPPED_REFUSAL, EmergencyStop, MotionCommand, Status, decode, encode
from runtime.wire.transport import publish
from tests.agent_hub import agent_on_hub as agent_on_hub_of

RUN = "agent-test"
EPOCH = 17  # the test acts as the coordinator of this epoch


@pytest.fixture
def agent_on_hub():
    with agent_on_hub_of(RUN, EPOCH, np.zeros(3), robot_key(RUN, 0, "status")) as running:
        yield running


def next_status(statuses: queue.Queue, timeout: float = 3.0) -> Status:
    _, payload = statuses.get(timeout=timeout)
    return decode(payload, Status)


def send(hub, step: int, turn: float, drive: float, cmd_id: int = 0) -> None:
    publish(hub, robot_key(RUN, 0, "cmd"),
            encode(MotionCommand(run=RUN, step=step, robot=0, config=1, turn_rad=turn, drive_m=drive, cmd_id=cmd_id, epoch=EPOCH)))


def test_command_beyond_limits_is_refused_with_a_reason_and_not_executed(agent_on_hub):
    hub, agent, statuses = agent_on_hub
    send(hub, 1, 0.1, 5.0)  # the default limit is 1 m
    status = next_status(statuses)
    assert status.state == "refused" and "drive" in status.reason
    assert agent.executed == 0


def test_duplicate_command_is_not_executed_twice(agent_on_hub):
    hub, agent, statuses = agent_on_hub
    send(hub, 1, 0.2, 0.1)
    assert next_status(statuses).state == "done"  # a motion of no wall time: done alone
    send(hub, 1, 0.2, 0.1)
    assert next_status(statuses).state == "done"  # the last status again
    assert agent.executed == 1
    send(hub, 0, 0.2, 0.1)
    stale = next_status(statuses)
    assert stale.state == "refused" and "stale" in stale.reason


def test_garbage_on_the_command_key_is_dropped_and_counted(agent_on_hub):
    hub, agent, statuses = agent_on_hub
    for junk in (b"", b"\xc1", b"\x92\x01\x02", encode(MotionCommand(run=RUN, step=1, robot=0, config=1, turn_rad=0.0, drive_m=0.1))[:-3]):
        publish(hub, robot_key(RUN, 0, "cmd"), junk)
    deadline = time.monotonic() + 3
    while agent.drops.total < 4 and time.monotonic() < deadline:
        time.sleep(0.02)
    assert agent.drops.total == 4
    send(hub, 1, 0.0, 0.1)  # still serving
    assert next_status(statuses).state == "done"


def test_every_status_echoes_the_command_id(agent_on_hub):
    hub, agent, statuses = agent_on_hub
    send(hub, 1, 0.2, 0.1, cmd_id=77)
    done = next_status(statuses)
    assert (done.state, done.cmd_id) == ("done", 77)
    send(hub, 0, 0.2, 0.1, cmd_id=5)  # a replayed old command: refused with its own id, which no coordinator waits for
    stale = next_status(statuses)
    assert (stale.state, stale.cmd_id) == ("refused", 5)


def test_a_command_for_a_later_step_is_refused_unremembered_and_the_real_one_runs(agent_on_hub):
    """A command for any step but the next (last observed step + 1 = 1 here) is refused and not remembered."""
    hub, agent, statuses = agent_on_hub
    send(hub, 3, 0.2, 0.1, cmd_id=9)
    early = next_status(statuses)
    assert (early.state, early.step, early.cmd_id) == ("refused", 3, 9) and "out of sequence" in early.reason
    send(hub, 1, 0.2, 0.1, cmd_id=10)
    assert next_status(statuses).state == "done"
    assert agent.executed == 1


def test_a_motion_that_takes_time_is_accepted_before_it_is_done():
    """A driver whose motions take wall time (0.2 s here) answers ``accepted`` at once and ``done`` once the motion
    is over, both echoing the command's id (in that order: one key keeps its order); one of no wall time answers
    ``done`` alone (the tests above)."""
    with agent_on_hub_of(RUN, EPOCH, np.zeros(3), robot_key(RUN, 0, "status"), motion_time_s=0.2) as (hub, agent, statuses):
        t0 = time.monotonic()
        send(hub, 1, 0.2, 0.1, cmd_id=31)
        got = [next_status(statuses), next_status(statuses)]
        t_done = time.monotonic() - t0
    assert [(s.state, s.cmd_id) for s in got] == [("accepted", 31), ("done", 31)]
    assert t_done >= 0.2


@pytest.mark.parametrize("robots, said", [((), f"{RUN_STOPPED_REFUSAL} by swarm estop (operator)"), ((0,), "emergency stop")])
def test_after_an_emergency_stop_a_command_is_refused_saying_whether_the_whole_run_was_stopped(agent_on_hub, robots, said):
    hub, agent, statuses = agent_on_hub
    publish(hub, estop_key(RUN), encode(EmergencyStop(run=RUN, step=0, source="swarm estop", reason="operator", robots=robots)))
    deadline = time.monotonic() + 3
    while not agent.estopped:
        assert time.monotonic() < deadline, "the stop was not heard"
        time.sleep(0.02)
    send(hub, 1, 0.1, 0.1)
    refusal = next_status(statuses)
    assert (refusal.state, refusal.reason) == ("refused", said) and agent.executed == 0
