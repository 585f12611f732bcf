"""Many robot agents in one process (robot_agent/host.py, ``swarm agent --id 0-49``, ``swarm launch
--agents-per-process``): each hosted agent is its own agent on the wire, and a run is bit-identical
to one process per agent. Real Zenoh sessions on loopback and real processes, stopped by pid.
"""

from __future__ import annotations

import contextlib
import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from inchworm.processes import agents_per_process
from robot_agent.agent import Agent
from robot_agent.assembly import format_ids, parse_ids
from robot_agent.driver import SimDriver
from robot_agent.host import AgentHost
from runtime.errors import SwarmInputError
from runtime.models.config import ModelConfig
from runtime.models.trajectory import random_trajectory
from runtime.wire.keys import alive_wildcard, parse_key, robot_key, robot_wildcard
from runtime.wire.messages import MotionCommand, Status, decode, encode
from runtime.wire.transport import alive_now, open_loopback_hub, publish, subscribe_queue
from tests.agent_hub import declare_coordinator

REPO = Path(__file__).resolve().parents[2]
ENV = {**os.environ, "PYTHONPATH": str(REPO)}
RUN = "host-test"


def test_id_lists_and_ranges():
    assert parse_ids("0-2,5,7-8", "--id") == [0, 1, 2, 5, 7, 8]
    assert parse_ids("4", "--id") == [4]
    assert format_ids([0, 1, 2, 5, 7, 8]) == "0-2,5,7-8"
    assert parse_ids(format_ids(range(500)), "--ids") == list(range(500))
    for bad, message in (("5-2", "a <= b"), ("-1", "ids >= 0"), ("a", "ids >= 0"), ("0-3,2", "twice"), ("", "ids >= 0")):
        with pytest.raises(SwarmInputError, match=message):
            parse_ids(bad, "--id")


def test_default_agents_per_process():
    assert agents_per_process(50, None) == 1  # one process per agent for small swarms
    assert agents_per_process(60, None) == 30  # 2 processes, balanced
    assert agents_per_process(500, None) == 50
    assert agents_per_process(500, 7) == 7
    with pytest.raises(SwarmInputError, match="^agents_per_process must be >= 1, got 0$"):
        agents_per_process(10, 0)


class ThreadRecordingDriver(SimDriver):
    """A simulated robot that records the thread each of its motions ran on."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.threads: list[int] = []

    def execute(self, command):
        self.threads.append(threading.get_ident())
        return super().execute(command)


@contextlib.contextmanager
def hosted_run(motion_time_s: float):
    """(hub, agents of robots 1-3 of [0..3] in one running host, the host, status queue, host.run()'s result list);
    the test is the coordinator of epoch 5. On leaving, the host is stopped, its thread joined and every token gone."""
    ids = [0, 1, 2, 3]
    hub, member, _ = open_loopback_hub()
    with hub:
        agents = [Agent(member, RUN, r, ids, ThreadRecordingDriver(r, ids, np.array([0.2 * r, 0.0, 0.0]), ModelConfig(), seed=1,
                                                                 motion_time_s=motion_time_s)) for r in (1, 2, 3)]
        host = AgentHost(member, agents)
        done: list[int] = []
        thread = threading.Thread(target=lambda: done.append(host.run()), daemon=True)
        thread.start()
        try:
            deadline = time.monotonic() + 10
            while sorted(parse_key(k).robot for k in alive_now(hub, alive_wildcard(RUN))) != [1, 2, 3]:
                assert time.monotonic() < deadline, "the hosted agents did not come up"
                time.sleep(0.02)
            _, statuses = subscribe_queue(hub, robot_wildcard(RUN, "status"))
            token = declare_coordinator(hub, RUN, 5, [1, 2, 3])
            yield hub, agents, host, thread, statuses, done
            token.undeclare()
        finally:
            host.stop()
            thread.join(timeout=10)
        deadline = time.monotonic() + 5
        while alive_now(hub, alive_wildcard(RUN)):
            assert time.monotonic() < deadline, "tokens of a stopped host are still alive"
            time.sleep(0.02)


def command_all(hub, statuses, robots, step: int = 1) -> list[tuple[int, str]]:
    for r in robots:
        publish(hub, robot_key(RUN, r, "cmd"), encode(MotionCommand(run=RUN, step=step, robot=r, config=1, turn_rad=0.1,
                                                                    drive_m=0.05, epoch=5)))
    got: list[tuple[int, str]] = []
    while sum(state == "done" for _, state in got) < len(robots):
        status = decode(statuses.get(timeout=10)[1], Status)
        got.append((status.robot, status.state))
    return sorted(got)


@pytest.mark.parametrize(("motion_time_s", "threads"), [(0.0, 1), (0.05, 3)])
def test_instantaneous_agents_share_one_thread_and_others_get_one_each(motion_time_s, threads):
    """Simulated robots without motion time are served by the host's one thread (each message wakes it, not one
    of 3 agent threads); robots whose motions take time (0.05 s) each run on their own thread, so one robot's
    motion never waits for another's. On the wire both are the same: each robot answers its own command."""
    with hosted_run(motion_time_s) as (hub, agents, host, thread, statuses, done):
        got = command_all(hub, statuses, [1, 2, 3])
        expected = [(r, "done") for r in (1, 2, 3)] + ([] if motion_time_s == 0 else [(r, "accepted") for r in (1, 2, 3)])
        assert got == sorted(expected)
        used = {t for a in agents for t in a.driver.threads}
        assert len(used) == threads and all(len(a.driver.threads) == 1 for a in agents)
        if threads == 1:
            assert used == {thread.ident}  # the host's own thread
    assert done == [0] and not thread.is_alive()


def test_a_robot_lost_in_a_host_ends_its_agent_only():
    """Robot 2's driver reports its robot lost while idle: its agent ends and drops its token, robots 1 and 3 keep
    serving (their next command is done) and the host returns 3 (a robot was lost) once stopped."""
    with hosted_run(0.0) as (hub, agents, host, thread, statuses, done):
        agents[1].driver.report_lost("radio link gone")
        deadline = time.monotonic() + 10
        while (alive := sorted(parse_key(k).robot for k in alive_now(hub, alive_wildcard(RUN)))) != [1, 3]:
            assert time.monotonic() < deadline, f"tokens alive: {alive}"
            time.sleep(0.02)
        assert command_all(hub, statuses, [1, 3]) == [(1, "done"), (3, "done")]
        assert agents[1].stopped and agents[1].lost_reason == "radio link gone" and agents[1].executed == 0
    assert done == [3] and host.results == {2: 3, 1: 0, 3: 0}


def test_hosted_agents_are_separate_agents_on_the_wire():
    """Three agents in one host: three tokens; a command to robot 2 is answered and executed by robot 2's agent
    alone; once stopped, the host returns 0 and every token is gone (``hosted_run`` checks)."""
    with hosted_run(0.0) as (hub, agents, host, thread, statuses, done):
        assert command_all(hub, statuses, [2]) == [(2, "done")]  # motions of no wall time: done alone
        assert [a.executed for a in agents] == [0, 1, 0]  # only robot 2's agent executed it
        moved = agents[1].driver.true_pose()
        assert not np.allclose(moved, [0.4, 0.0, 0.0]) and np.allclose(agents[0].driver.true_pose(), [0.2, 0.0, 0.0])
    assert done == [0]


def _launch(tmp: Path, traj_file: Path, name: str, *extra: str) -> str:
    result = tmp / f"{name}.json"
    proc = subprocess.run([sys.executable, "-m", "swarm_cli.main", "launch", f"--trajectory={traj_file}", "--seed=3",
                           "--method=inchworm", f"--result={result}", "--no-record", f"--out={tmp / name}", f"--run={name}-{os.getpid()}",
                           *extra], capture_output=True, text=True, timeout=300, cwd=REPO, env=ENV)
    assert proc.returncode == 0, proc.stderr
    return result.read_text()


def test_a_run_is_bit_identical_whatever_the_agents_per_process(tmp_path):
    traj_file = tmp_path / "traj.json"
    random_trajectory(5, 2, np.random.default_rng(8)).save(traj_file)
    one = _launch(tmp_path, traj_file, "one", "--agents-per-process=1")
    hosted = _launch(tmp_path, traj_file, "hosted", "--agents-per-process=3")  # processes of 3 + 2 agents
    assert json.loads(one)["steps"] and hosted == one


def test_hosted_gateway_agents_give_the_same_run(tmp_path):
    traj_file = tmp_path / "traj.json"
    random_trajectory(4, 1, np.random.default_rng(5)).save(traj_file)
    one = _launch(tmp_path, traj_file, "gw-one", "--driver=gateway", "--agents-per-process=1")
    hosted = _launch(tmp_path, traj_file, "gw-hosted", "--driver=gateway", "--agents-per-process=2")
    assert json.loads(one)["steps"] and hosted == one


@pytest.mark.parametrize("args,message", [
    (["--id=0-3", "--ids=0-2"], "--id names robots [3] that are not robots of the run"),
    (["--id=0-1", "--ids=0-3", "--pose=0,0,0"], "--pose is one robot's pose: give --trajectory FILE"),
    (["--id=2-1", "--ids=0-3"], "--id must be robot ids"),
    (["--id=0"], "--ids (every robot of the run, e.g. 0-9) or --trajectory FILE must be given"),
])
def test_agent_options_are_checked(args, message):
    proc = subprocess.run([sys.executable, "-m", "swarm_cli.agent", "--run=r", "--hub=tcp/127.0.0.1:9", *args],
                          capture_output=True, text=True, timeout=60, cwd=REPO, env=ENV)
    assert proc.returncode == 2 and message in proc.stderr and "Traceback" not in proc.stderr, proc.stderr
