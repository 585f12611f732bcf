"""Faults through the front door (docs/failure-model.md): ``swarm launch --kill-robot``, a coordinator that
dies or is stopped, hostile messages on every key. Real processes on loopback, each stopped by its pid."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from inchworm.bench.faults import lost_robot
from inchworm.processes import stop_all
from runtime.recording.mcap_log import read_messages
from runtime.wire.messages import EmergencyStop, decode

REPO = Path(__file__).resolve().parents[2]
ENV = {**os.environ, "PYTHONPATH": str(REPO)}


def _children_of(pid: int) -> list[int]:
    """Pids of the live processes whose parent is ``pid``."""
    out = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue
            fields = stat[stat.rindex(")") + 2:].split()
            if int(fields[1]) == pid and fields[0] != "Z":
                out.append(int(entry.name))
    return out


def _cmdline(pid: int) -> str:
    try:
        return (Path("/proc") / str(pid) / "cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return ""


def launch(tmp: Path, *options: str, stderr=subprocess.PIPE) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "swarm_cli.main", "launch", "--no-record", f"--out={tmp}", *options],
                            stdout=subprocess.PIPE, stderr=stderr, text=True, cwd=tmp, env=ENV)


def test_kill_robot_through_launch_over_seeds_completes_with_the_others():
    """``swarm bench faults``' lost-robot part: ``swarm launch -n 4 --configs 2 --kill-robot 2@2 --json`` for seeds 0-2."""
    result = lost_robot(3, robots=4, configs=2, victim=2, step=2)
    assert result["completed"] and result["runs_completed"] == 3, result
    for summary in result["summaries"]:
        assert summary["finished_robots"] == 3 and len(summary["configs"]) == 2
        assert [(lost["robot"], lost["reason"]) for lost in summary["lost"]] == [(2, "liveliness token gone")]
        kill = summary["kill"]
        assert (kill["robot"], kill["step"]) == (2, 2)
        assert 0 < kill["detect_ms"] <= kill["estop_ms"]  # the stop is stamped before it is heard
    assert result["detect_ms_median"] == sorted(s["kill"]["detect_ms"] for s in result["summaries"])[1]
    assert result["estop_ms_max"] == max(s["kill"]["estop_ms"] for s in result["summaries"])


def test_kill_robot_given_three_times_kills_each(tmp_path):
    """``--kill-robot`` is repeatable: three robots of a 6-robot run are each SIGKILLed at their step, each is lost and
    reported (``"kills"``, ``"kill"`` the first), and the other three finish."""
    proc = subprocess.run([sys.executable, "-m", "swarm_cli.main", "launch", "-n=6", "--configs=2", "--seed=0",
                           "--kill-robot=1@1", "--kill-robot=3@2", "--kill-robot=4@2", "--no-record", f"--out={tmp_path}", "--json"],
                          capture_output=True, text=True, cwd=tmp_path, env=ENV, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    summary = json.loads(proc.stdout.strip().splitlines()[-1])
    assert sorted(lost["robot"] for lost in summary["lost"]) == [1, 3, 4] and summary["finished_robots"] == 3
    assert [(k["robot"], k["step"]) for k in summary["kills"]] == [(1, 1), (3, 2), (4, 2)] and summary["kill"] == summary["kills"][0]
    assert all(0 < k["detect_ms"] <= k["estop_ms"] for k in summary["kills"])
    assert proc.stderr.count("killed the agent of robot") == 3


def test_kill_robot_of_a_gateway_run_kills_its_port_process_and_the_others_complete(tmp_path):
    """``swarm launch --driver gateway`` hosts each radio port's link and agents in one process: ``--kill-robot 5@2``
    SIGKILLs that process, so the coordinator loses the three robots of robot 5's port (ports of five: 0-4, 5-7) and
    finishes with the other five."""
    proc = subprocess.run([sys.executable, "-m", "swarm_cli.main", "launch", "--driver=gateway", "-n=8", "--configs=2", "--seed=1",
                           "--kill-robot=5@2", "--no-record", f"--out={tmp_path}", "--json"],
                          capture_output=True, text=True, cwd=tmp_path, env=ENV, timeout=300)
    summary = json.loads(proc.stdout.strip().splitlines()[-1])
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert summary["finished_robots"] == 5 and len(summary["configs"]) == 2
    assert sorted(lost["robot"] for lost in summary["lost"]) == [5, 6, 7]
    assert 0 < summary["kill"]["detect_ms"] <= summary["kill"]["estop_ms"] and "Traceback" not in proc.stderr


def test_a_coordinator_killed_under_launch_gets_every_robot_stopped(tmp_path):
    log = tmp_path / "launch.log"
    with open(log, "w") as stderr:
        proc = launch(tmp_path, "-n=4", "--configs=6", "--motion-time=0.3", stderr=stderr)
    try:
        deadline = time.monotonic() + 60
        coordinator = None
        while coordinator is None:
            assert time.monotonic() < deadline and proc.poll() is None, "no coordinator process"
            coordinator = next((p for p in _children_of(proc.pid) if "inchworm.spawn - coordinator" in _cmdline(p)), None)
            time.sleep(0.05)
        agents = [p for p in _children_of(proc.pid) if "inchworm.spawn - agent" in _cmdline(p)]
        assert len(agents) == 4
        while "config 1/6 done" not in log.read_text():  # the run is moving
            assert time.monotonic() < deadline and proc.poll() is None, log.read_text()
            time.sleep(0.05)
        os.kill(coordinator, signal.SIGKILL)
        proc.communicate(timeout=60)
    finally:
        stop_all([proc])
    err = log.read_text()
    assert proc.returncode == 128 + signal.SIGKILL
    assert "the coordinator exited with status -9: emergency stop sent" in err
    for robot in range(4):
        assert f"robot {robot}: emergency stop" in err
    assert all(_cmdline(p) == "" for p in agents)  # no process left behind


def test_sigterm_of_the_coordinator_publishes_a_run_wide_stop(tmp_path):
    import numpy as np
    from test_distributed import Run, _wait_for_command

    from runtime.models.trajectory import random_trajectory

    run = Run(tmp_path, random_trajectory(4, 6, np.random.default_rng(2)), "ref57", 2, motion_time=0.3)
    try:
        run.start()
        _wait_for_command(run)
        run.coordinator.send_signal(signal.SIGTERM)
        run.finish(60)
        stops = [decode(p) for k, p, _t, _pub in read_messages(run.recording) if k.endswith("/estop")]
        assert [list(s.robots) for s in stops] == [[]] and all(isinstance(s, EmergencyStop) for s in stops)
        assert "the run ended early (StopRequested: SIGTERM)" in stops[0].reason
    finally:
        run.stop()


def test_bench_faults_json_contract_and_every_fault_survived(tmp_path):
    """``swarm bench faults --json`` at a small size: radio faults at 5 % each (one seed, against its fault-free
    run), a killed agent, a killed coordinator with a standby (paper and joint localizers), and 2000 hostile messages (random bytes, wrong types,
    NaN/inf/huge values, future steps, unknown ids, replays) on every key: every run completes with the same table
    and P_f; emergency stops through the TLS router's operator listener, one a second while 3000 idle connections are
    held on its public listener for 3 s (``--flood-s=3``) and 3 s after, reach every robot within 1 s;
    LinkRequests forged through the gateway identity during and after a run move no robot; a killed agent restarted
    out of everybody's 0.5 m range rejoins; a coordinator stalled 12 s hands over to its standby."""
    proc = subprocess.run([sys.executable, "-m", "swarm_cli.main", "bench", "faults", "--seeds=1", "--fuzz=2000",
                           "--gateway-rows=0.05,0.05,0.05", "--flood-s=3", "--json"], capture_output=True, text=True, cwd=tmp_path, env=ENV,
                          timeout=900)
    assert proc.returncode == 0, proc.stderr
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    assert list(result) == ["gateway", "lost_robot", "fuzz", "coordinator", "estop_under_flood", "coordinator_joint", "forged_link_requests",
                            "rejoin", "coordinator_stall"]
    assert result["rejoin"] == {"runs": 1, "rejoined": 1, "sensing_range_m": 0.5}  # a killed agent restarted out of range
    assert result["coordinator_stall"] == {"stall_s": 12.0, "runs": 1, "completed": 1}  # beyond the lease, with a standby
    assert result["gateway"] == [{"drop": 0.05, "corrupt": 0.05, "delay": 0.05, "runs": 1, "completed": 1, "identical": 1,
                                  "max_executions_per_step": 1}]
    lost = result["lost_robot"]
    assert list(lost) == ["detect_ms_median", "completed", "estop_ms_max"] and lost["completed"] is True
    assert 0 < lost["detect_ms_median"] <= lost["estop_ms_max"]
    assert result["fuzz"] == {"sent": 2000, "process_deaths": 0, "completed": True, "identical": True}
    coordinator = result["coordinator"]  # the coordinator SIGKILLed at a random step, a standby taking over
    assert list(coordinator) == ["runs", "completed", "identical", "takeover_ms_max"]
    assert coordinator["runs"] == coordinator["completed"] == coordinator["identical"] == 1
    assert 0 < coordinator["takeover_ms_max"] < 1000
    joint = result["coordinator_joint"]  # the same with the joint localizer: its joint covariance travels in the checkpoint
    assert list(joint) == list(coordinator) and joint["runs"] == joint["completed"] == joint["identical"] == 1
    flood = result["estop_under_flood"]
    assert list(flood) == ["connections", "tls", "robots", "reached", "ms_max", "duration_s", "after_s", "stops", "late", "probes",
                           "public_blocked"]
    assert (flood["connections"], flood["tls"], flood["reached"]) == (3000, True, flood["robots"]) and flood["robots"] >= 10
    assert (flood["duration_s"], flood["after_s"], flood["late"]) == (3.0, 3.0, 0) and flood["stops"] == flood["probes"] >= 4
    assert flood["ms_max"] < 1000
    forged = result["forged_link_requests"]  # the gateway identity forging LinkRequests during and after a run
    assert list(forged) == ["sent", "executed", "completed"] and forged["sent"] > 20
    assert forged["executed"] == 0 and forged["completed"] is True


def test_bench_faults_refuses_a_flood_out_of_range_before_running_anything(capsys):
    from swarm_cli.main import main as swarm_main

    assert swarm_main(["bench", "faults", "--flood-s=0.5"]) == 2
    assert swarm_main(["bench", "faults", "--flood=0"]) == 2
    err = capsys.readouterr().err
    assert "--flood-s must be between 1 and 3600, got 0.5" in err and "--flood must be >= 1, got 0" in err and "Traceback" not in err
