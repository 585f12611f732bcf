"""One master per run and a run that survives its coordinator (docs/protocol.md, Coordinator epochs;
docs/failure-model.md). Real agent and coordinator processes on a loopback hub, each stopped by its pid."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from coordinator.replay_check import check, load_recording
from inchworm.processes import start_agents, stop_all
from inchworm.specs import AgentHostSpec
from runtime.models.trajectory import random_trajectory
from runtime.recording.mcap_log import read_messages
from runtime.wire.keys import alive_wildcard, coord_alive_key, coord_key, robot_key, robot_wildcard
from runtime.wire.messages import MotionCommand, PlanMessage, Status, decode, encode
from runtime.wire.transport import (
    alive_now,
    free_tcp_port,
    loopback_hub,
    open_loopback_hub,
    open_session,
    publish,
    subscribe,
    subscribe_queue,
)
from tests.agent_hub import declare_coordinator
from tests.waiting import wait_for

REPO = Path(__file__).resolve().parents[2]
ENV = {**os.environ, "PYTHONPATH": str(REPO)}



def _coordinator(traj_file: Path, run_id: str, hub: str, seed: int, *extra: str) -> subprocess.Popen:
    record = [] if any(e.startswith("--record=") for e in extra) else ["--no-record"]
    return subprocess.Popen([sys.executable, "-m", "swarm_cli.coordinator_cmd", f"--trajectory={traj_file}", "--method=ref57",
                             f"--run={run_id}", f"--hub={hub}", f"--seed={seed}", *record, "--json", *extra],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=traj_file.parent, env=ENV)


def _run_with_agents(tmp_path: Path, run_id: str, robots: int = 4, configs: int = 3, seed: int = 2):
    traj = random_trajectory(robots, configs, np.random.default_rng(seed))
    traj_file = tmp_path / "traj.json"
    traj.save(traj_file)
    port = free_tcp_port()
    hub_settings, member = loopback_hub(port)
    return traj, traj_file, hub_settings, f"tcp/127.0.0.1:{port}"


def test_a_second_coordinator_on_a_live_run_is_refused_and_the_first_finishes_alone(tmp_path):
    traj, traj_file, hub_settings, hub = _run_with_agents(tmp_path, "twomasters")
    procs: list[subprocess.Popen] = []
    commands: list[MotionCommand] = []
    with open_session(hub_settings) as session:
        subscribe(session, robot_wildcard("twomasters", "cmd"), lambda key, payload: commands.append(decode(payload, MotionCommand)))
        try:
            # the first coordinator is live (its token declared, waiting for its agents) however slow the machine
            first = _coordinator(traj_file, "twomasters", hub, 2, "--result=first.json")
            procs.append(first)
            wait_for(lambda: alive_now(session, coord_alive_key("twomasters")), 60, "the first coordinator's token")
            second = _coordinator(traj_file, "twomasters", hub, 5)
            procs.append(second)
            _, err2 = second.communicate(timeout=60)
            start_agents(traj, AgentHostSpec(run_id="twomasters", robots=(), hub=hub, seed=2, motion_time=0.1), procs,
                         env=ENV, stderr=subprocess.DEVNULL)
            out1, err1 = first.communicate(timeout=120)
        finally:
            stop_all(procs)
    assert second.returncode == 4, err2
    lines = [line for line in err2.splitlines() if line.strip()]
    assert len(lines) == 1 and "run twomasters already has a live coordinator (epoch " in lines[0], err2
    assert "Traceback" not in err2
    assert first.returncode == 0, err1[-2000:]
    summary = json.loads(out1.strip().splitlines()[-1])
    assert summary["lost"] == [] and len(summary["configs"]) == 3
    assert len({c.epoch for c in commands}) == 1  # every command came from the first coordinator
    assert str(commands[0].epoch) in lines[0]


def test_replay_refuses_a_live_run_and_publishes_under_a_new_run_id(tmp_path):
    traj, traj_file, hub_settings, hub = _run_with_agents(tmp_path, "live")
    procs: list[subprocess.Popen] = []
    # a recording of a finished run (its own hub), replayed onto the hub of a live run with the same id
    recording = tmp_path / "rec.mcap"
    rec_traj = tmp_path / "rec"
    rec_traj.mkdir()
    done = subprocess.run([sys.executable, "-m", "swarm_cli.main", "launch", "-n=4", "--configs=2", "--method=ref57",
                           "--run=live", f"--record={recording}", f"--out={rec_traj}"],
                          capture_output=True, text=True, cwd=tmp_path, env=ENV, timeout=180)
    assert done.returncode == 0, done.stderr[-2000:]
    heard: list[str] = []
    with open_session(hub_settings) as session:
        subscribe(session, "swarm/**", lambda key, payload: heard.append(key))
        try:
            start_agents(traj, AgentHostSpec(run_id="live", robots=(), hub=hub, seed=2, motion_time=0.0), procs,
                         env=ENV, stderr=subprocess.DEVNULL)
            wait_for(lambda: len(alive_now(session, alive_wildcard("live"))) == traj.n, 60, "the live run's agents")
            refused = subprocess.run([sys.executable, "-m", "swarm_cli.main", "replay", str(recording), "--publish", "--same-run",
                                      "--speed=0", f"--hub={hub}", "--wait=0"],
                                     capture_output=True, text=True, cwd=tmp_path, env=ENV, timeout=60)
            time.sleep(0.3)
            refused_heard = [k for k in heard if "/robot/" in k and k.endswith(("/cmd", "/observe"))]
            heard.clear()
            moved = subprocess.run([sys.executable, "-m", "swarm_cli.main", "replay", str(recording), "--publish", "--speed=0",
                                    f"--hub={hub}", "--wait=0"],
                                   capture_output=True, text=True, cwd=tmp_path, env=ENV, timeout=60)
            if moved.returncode == 0:
                wait_for(lambda: heard, 10, "the replayed messages")
        finally:
            stop_all(procs)
    assert refused.returncode == 2, refused.stderr
    assert "run live is live on this hub (agents of robots 0, 1, 2, 3)" in refused.stderr and "Traceback" not in refused.stderr
    assert refused_heard == []  # nothing was published
    assert moved.returncode == 0, moved.stderr
    new_run = moved.stdout.split(" messages of run ", 1)[1].split(" ", 1)[0]
    assert new_run.startswith("live-replay-")
    replayed = [k for k in heard if k.startswith("swarm/")]
    assert replayed and all(k.startswith(f"swarm/{new_run}/") for k in replayed)


def test_a_command_of_a_gone_coordinator_epoch_is_refused(tmp_path):
    """A real agent process obeys epoch 11; once that token is gone and epoch 12 runs a new run, a command of 11
    (stale) is refused naming it, and epoch 12's step 1 runs."""
    hub_session, _, endpoint = open_loopback_hub()
    agent = subprocess.Popen([sys.executable, "-m", "swarm_cli.agent", "--id=0", "--ids=0,1", "--pose=0,0,0", "--run=stale",
                              f"--hub={endpoint}"], env=ENV, stderr=subprocess.DEVNULL)
    try:
        with hub_session as hub:
            wait_for(lambda: alive_now(hub, alive_wildcard("stale")), 30, "the agent's token")
            _, statuses = subscribe_queue(hub, robot_key("stale", 0, "status"))

            def command(epoch: int, step: int) -> list[Status]:
                cmd = MotionCommand(run="stale", step=step, robot=0, config=1, turn_rad=0.1, drive_m=0.05, cmd_id=epoch, epoch=epoch)
                publish(hub, robot_key("stale", 0, "cmd"), encode(cmd))
                got = [decode(statuses.get(timeout=5)[1], Status)]
                while got[-1].state == "accepted":
                    got.append(decode(statuses.get(timeout=5)[1], Status))
                return got

            old = declare_coordinator(hub, "stale", 11, [0])
            assert [s.state for s in command(11, 1)] == ["done"]
            old.undeclare()
            new = declare_coordinator(hub, "stale", 12, [0])  # after 11's token went: the agent saw both, in order
            stale = command(11, 2)
            assert [s.state for s in stale] == ["refused"]
            assert "coordinator epoch 11, which is gone" in stale[0].reason
            assert [s.state for s in command(12, 1)] == ["done"]  # a new run: step 1 again
            assert [s.state for s in command(11, 2)] == ["refused"]  # still refused while 12 is alive
            new.undeclare()
    finally:
        agent.send_signal(signal.SIGTERM)
        agent.wait(timeout=10)


def test_sigkill_of_the_coordinator_at_a_random_step_the_standby_finishes_the_run_bit_for_bit(tmp_path):
    """``swarm launch --standby --kill-coordinator STEP``: the standby takes over within 1 s and the run's every
    estimate (with covariance), truth and P_f equal the fault-free run of the same seed."""
    seed, robots, configs = 4, 6, 3
    step = int(np.random.default_rng().integers(1, 7))  # ref57 on 6 robots: two steps per configuration
    runs = {}
    for name, extra in (("clean", []), ("killed", ["--standby", f"--kill-coordinator={step}"])):
        folder = tmp_path / name
        folder.mkdir()
        proc = subprocess.run([sys.executable, "-m", "swarm_cli.main", "launch", f"-n={robots}", f"--configs={configs}",
                               f"--seed={seed}", "--method=ref57", "--motion-time=0.05", "--no-record", f"--out={folder}",
                               f"--result={folder / 'result.json'}", "--json", *extra],
                              capture_output=True, text=True, cwd=folder, env=ENV, timeout=300)
        assert proc.returncode == 0, proc.stderr[-3000:]
        runs[name] = (json.loads(proc.stdout.strip().splitlines()[-1]), json.loads((folder / "result.json").read_text()), proc.stderr)
    (clean, clean_result, _), (killed, killed_result, err) = runs["clean"], runs["killed"]
    assert "the standby takes over" in err and "takes over run" in err, err[-2000:]
    kill = killed["coordinator_kill"]
    assert kill["step"] == step and 0 < kill["takeover_ms"] < 1000
    assert killed_result == clean_result  # every step's estimate, covariance and truth, bit for bit
    assert killed["pf"] == clean["pf"] and killed["configs"] == clean["configs"] and killed["lost"] == []


@pytest.mark.parametrize("rejoin", ["yes", "no"])
def test_a_lost_robot_whose_agent_comes_back_rejoins_and_the_run_completes(tmp_path, rejoin):
    """SIGKILL robot 2's agent when step 2 starts, restart it (same id, where the robot stands) at the default 0.5 m
    sensing range once the swarm moved on: it rejoins at the next configuration (from what it sees of its neighbours or,
    seeing fewer than two, at its last estimate, dead reckoning bringing it among them: which, depends on where the
    run is when its agent is up; tests/unit/test_lost_robots.py checks the second deterministically), the run completes
    with it localized, and the restarted agent drops no message (``--rejoin no``: it stays out, as before). The joint
    localizer's run, recorded, replays bit for bit through the loss (its joint covariance marginalised) and the
    rejoin (``executor.localize_rejoined``)."""
    traj, traj_file, hub_settings, hub = _run_with_agents(tmp_path, "rejoin", robots=6, configs=5, seed=3)
    procs: list[subprocess.Popen] = []
    truths: dict[int, list[float]] = {}
    started = []
    restarted_err = (tmp_path / "restarted.err").open("w")
    with open_session(hub_settings) as session:
        from runtime.wire.messages import TruthMessage

        subscribe(session, "swarm/rejoin/sim/truth/2", lambda key, payload: truths.update({2: list(decode(payload, TruthMessage).pose)}))
        subscribe(session, robot_wildcard("rejoin", "cmd"), lambda key, payload: started.append(decode(payload, MotionCommand).step))
        try:
            start_agents(traj, AgentHostSpec(run_id="rejoin", robots=(), hub=hub, seed=3, motion_time=0.4), procs,
                         env=ENV, stderr=subprocess.DEVNULL)
            coordinator = _coordinator(traj_file, "rejoin", hub, 3, "--result=result.json", f"--rejoin={rejoin}", "--localizer=joint",
                                       "--record=run.mcap")
            procs.append(coordinator)
            wait_for(lambda: any(s >= 2 for s in started), 60, "step 2")
            victim = procs[2]
            victim.send_signal(signal.SIGKILL)
            victim.wait(timeout=10)
            wait_for(lambda: any(s >= 7 for s in started), 60, "step 7")  # the swarm moves on, out of its sensing range
            x, y, heading = truths[2]
            procs.append(subprocess.Popen([sys.executable, "-m", "swarm_cli.agent", "--id=2", f"--ids={','.join(map(str, traj.ids))}",
                                           f"--pose={x!r},{y!r},{heading!r}", "--motion-time=0.4", "--run=rejoin", f"--hub={hub}",
                                           "--seed=3"], env=ENV, stderr=restarted_err))
            out, err = coordinator.communicate(timeout=180)
        finally:
            stop_all(procs)
    restarted_err.close()
    assert coordinator.returncode == 0, err[-3000:]
    result = json.loads((tmp_path / "result.json").read_text())
    assert [lost["robot"] for lost in result["lost"]] == [2], (result["lost"], err[-3000:])
    assert "dropped" not in (tmp_path / "restarted.err").read_text()
    checked = check(load_recording(tmp_path / "run.mcap"))
    assert checked.passed and checked.skipped == [], (checked.divergence, checked.skipped)
    assert checked.estimates == len(result["steps"]) + 1 + (rejoin == "yes")  # the rejoin's own estimate
    # every plan reproduced: one per configuration and those of its approach legs (without the loss: robots 2, 4 and 5
    # drive into places 5.9-6.9 cm apart in configuration 1, contact probability 3 % at their straight drives' ends, two
    # more legs; one more in configuration 5); how many depends on where the loss and the rejoin fall: counted from the
    # recording
    legs = [decode(payload, PlanMessage).leg for key, payload, _t, _pub in read_messages(tmp_path / "run.mcap")
            if key == coord_key("rejoin", "plan")]
    assert checked.plans == len(legs) and legs.count(0) == 5
    if rejoin == "no":
        assert result["rejoined"] == [] and 2 not in result["steps"][-1]["ids"] and "rejoined" not in out
        return
    assert [back["robot"] for back in result["rejoined"]] == [2]
    assert result["rejoined"][0]["config"] > result["lost"][0]["config"]
    last = result["steps"][-1]
    assert 2 in last["ids"] and len(last["ids"]) == 6  # it finished the run with the others
    row = last["ids"].index(2)
    assert np.linalg.norm(np.subtract(last["poses"][row][:2], last["truth"][row][:2])) < 0.1  # localized, not guessed
    assert "robot 2 rejoined after step" in out


def test_a_coordinator_resumed_from_the_recording_of_a_killed_one_finishes_the_run_bit_for_bit(tmp_path):
    """SIGKILL the coordinator (no standby) when step 3 starts; ``swarm coordinator --resume`` its recording: the run
    completes with every estimate and truth equal to the fault-free run of the same seed."""
    results = {}
    for name in ("clean", "resumed"):
        folder = tmp_path / name
        folder.mkdir()
        traj, traj_file, hub_settings, hub = _run_with_agents(folder, name, robots=6, configs=3, seed=6)
        procs: list[subprocess.Popen] = []
        started: list[int] = []
        with open_session(hub_settings) as session:
            subscribe(session, robot_wildcard(name, "cmd"), lambda key, payload, started=started: started.append(decode(payload, MotionCommand).step))
            try:
                start_agents(traj, AgentHostSpec(run_id=name, robots=(), hub=hub, seed=6, motion_time=0.05), procs,
                         env=ENV, stderr=subprocess.DEVNULL)
                first = _coordinator(traj_file, name, hub, 6, "--result=result.json", "--record=run.mcap")
                procs.append(first)
                if name == "resumed":
                    wait_for(lambda started=started: any(s >= 3 for s in started), 60, "step 3")
                    first.send_signal(signal.SIGKILL)
                    first.wait(timeout=10)
                    resumed = _coordinator(traj_file, name, hub, 6, "--result=result.json", "--resume=run.mcap")
                    procs.append(resumed)
                    out, err = resumed.communicate(timeout=120)
                    assert resumed.returncode == 0, err[-3000:]
                    assert "takes over run resumed from epoch" in err
                else:
                    out, err = first.communicate(timeout=120)
                    assert first.returncode == 0, err[-3000:]
            finally:
                stop_all(procs)
        results[name] = json.loads((folder / "result.json").read_text())
    assert results["resumed"] == results["clean"]
