"""How a launched run ends when its recording fails, when lost robots end it, and when the coordinator stalls.

Real processes (``swarm launch``: hub, agents, coordinator), faults injected through what a user has: a file-size
limit (RLIMIT_FSIZE, as a full disk: writes fail with EFBIG; Python ignores SIGXFSZ), ``--kill-robot``, SIGSTOP.
"""

from __future__ import annotations

import json
import os
import resource
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from inchworm.processes import start_agents, stop_all
from inchworm.specs import AgentHostSpec
from runtime.models.config import ModelConfig
from runtime.models.trajectory import body_spacing, random_trajectory
from runtime.recording.mcap_log import read_messages, recording_info
from runtime.wire.messages import Checkpoint, decode
from tests.routers import start_router

REPO = Path(__file__).resolve().parents[2]
ENV = {**os.environ, "PYTHONPATH": str(REPO)}
# bytes: this run's recording (~825 kB with its checkpoints; the first configuration, 19 steps with its approach legs,
# below, fits) outgrows it in the second configuration; its result (~98 kB) and plots (~139 kB) do not
RECORD_LIMIT = 350_000


def _launch(tmp_path: Path, *args: str, preexec=None, timeout: float = 180) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "swarm_cli.main", "launch", f"--out={tmp_path / 'out'}", f"--result={tmp_path / 'result.json'}",
           f"--record={tmp_path / 'run.mcap'}", "--json", *args]
    return subprocess.run(cmd, cwd=tmp_path, env=ENV, capture_output=True, text=True, timeout=timeout, preexec_fn=preexec)


def _file_limit() -> None:
    resource.setrlimit(resource.RLIMIT_FSIZE, (RECORD_LIMIT, RECORD_LIMIT))


@pytest.mark.parametrize("policy", ["continue", "stop"])
def test_a_recording_that_fails_mid_run_loses_nothing_else(tmp_path: Path, policy: str) -> None:
    proc = _launch(tmp_path, "-n", "10", "--configs", "2", "--method=one-at-a-time", "--run=fullrec",
                   f"--on-record-error={policy}", preexec=_file_limit)
    err = proc.stderr
    assert proc.returncode == 5, err[-3000:]
    failures = [line for line in err.splitlines() if "failed after" in line and line.startswith("coordinator: error: recording to")]
    assert len(failures) == 1 and "File too large" in failures[0], err[-3000:]  # one clear line, at once
    assert "Traceback" not in err and "callback" not in err, err[-3000:]
    summary = json.loads(proc.stdout.splitlines()[-1])
    assert summary["recording"] is None and summary["lost"] == [] and len(summary["plots"]) == 2
    assert len(summary["configs"]) == (2 if policy == "continue" else 1)  # stop: the run ends halfway
    assert all(Path(p).stat().st_size > 0 for p in summary["plots"])
    result = json.loads((tmp_path / "result.json").read_text())
    # every step done is kept: 10 robots x 2 configurations one at a time, and 15 steps of approach legs (robots 0/9,
    # 1/3 and 4/7 drive 0.25-0.37 m into places 8.9-9.3 cm apart, where their straight drives' ends touch with probability
    # 1.2e-3-5.3e-3, and other ends are over the legs' END_BOUND, 1e-4: 9 robots of configuration 1 and 6 of
    # configuration 2 stop at staging points and then drive on, one at a time)
    assert len(result["steps"]) == 35 if policy == "continue" else len(result["steps"]) < 35
    assert "recording failed: recording to" in proc.stdout and "P_f = " in proc.stdout
    info = recording_info(tmp_path / "run.mcap")  # kept as far as it got, readable
    assert info["messages"] > 100 and not info["complete"]
    assert "swarm launch: recording " in err and "is incomplete: the recording failed" in err, err[-3000:]  # not "recording X"
    stopped = [line for line in err.splitlines() if line.endswith(": emergency stop")]  # each agent's "robot N: emergency stop"
    if policy == "stop":
        assert len(stopped) == 10  # the run was stopped as an error: every robot stopped
        # stopped before the next step: no step after the one during which the recording failed (the recorder writes in
        # order, so that step's checkpoint is the first thing that did not reach the disk)
        checkpoints = [decode(payload, Checkpoint).step for topic, payload, _, _ in read_messages(tmp_path / "run.mcap")
                       if topic == "swarm/fullrec/coord/checkpoint"]
        assert len(result["steps"]) <= max(checkpoints) + 1, (len(result["steps"]), max(checkpoints))
    else:
        assert not stopped and "emergency stop sent" not in err  # a completed run is not e-stopped by the launcher


def test_a_run_ended_by_lost_robots_exits_3_naming_them_with_the_completed_configurations(tmp_path: Path) -> None:
    proc = _launch(tmp_path, "-n", "4", "--configs", "3", "--run=lostend", "--kill-robot=2@3", "--min-robots=4")  # config 1: 2 steps
    assert proc.returncode == 3, proc.stderr[-3000:]
    assert "robot 2" in proc.stderr and "fewer than the minimum 4" in proc.stderr
    assert "lost robot 2 after step" in proc.stdout and "Traceback" not in proc.stderr
    summary = json.loads(proc.stdout.splitlines()[-1])
    assert [lost["robot"] for lost in summary["lost"]] == [2] and len(summary["configs"]) == 1
    assert len(json.loads((tmp_path / "result.json").read_text())["steps"]) >= 1
    assert (tmp_path / "out" / "trajectory.png").exists()


def test_answers_received_during_a_coordinator_stall_count(tmp_path: Path) -> None:
    """The coordinator is stopped for 6 s (longer than the 5 s step timeout) while its robots answer within
    a second: on resuming it counts the answers already queued, and no robot is declared lost."""
    cmd = [sys.executable, "-m", "swarm_cli.main", "launch", "-n", "4", "--configs", "4", "--motion-time=0.4", "--run=stall",
           "--no-record", f"--out={tmp_path / 'out'}", "--json"]
    proc = subprocess.Popen(cmd, cwd=tmp_path, env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    lines: list[str] = []
    running = threading.Event()

    def read() -> None:
        for line in proc.stderr:
            lines.append(line)
            if "agents alive" in line:
                running.set()

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    try:
        assert running.wait(120), "".join(lines)
        coordinator = int(subprocess.run(["pgrep", "-P", str(proc.pid), "-f", "inchworm.spawn - coordinator"],
                                         capture_output=True, text=True).stdout.split()[0])
        time.sleep(0.6)  # in the middle of a step's wait
        os.kill(coordinator, signal.SIGSTOP)
        time.sleep(6.0)
        os.kill(coordinator, signal.SIGCONT)
        proc.wait(timeout=120)  # the reader thread drains stderr; stdout is the short summary
        reader.join(10)
        out = proc.stdout.read()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, "".join(lines)[-3000:]
    summary = json.loads(out.splitlines()[-1])
    assert summary["lost"] == [] and summary["finished_robots"] == 4, "".join(lines)[-3000:]


def test_a_coordinator_that_loses_its_hub_says_so_and_blames_no_robot(tmp_path: Path) -> None:
    """The router is SIGKILLed after the first configuration: every agent's token vanishes from the coordinator's view
    with it, but the robots are not lost and no stop can be sent. One line names the hub; ``--json`` has no lost robot
    and says why the run ended early; exit 3."""
    traj = random_trajectory(3, 4, np.random.default_rng(0), **body_spacing(ModelConfig()))
    traj.save(tmp_path / "traj.json")
    procs: list[subprocess.Popen] = []
    hub = start_router(procs, ENV)
    router = procs[0]
    try:
        start_agents(traj, AgentHostSpec(run_id="hubgone", robots=(), hub=hub, seed=0, motion_time=0.5), procs,
                         env=ENV, stderr=subprocess.DEVNULL)
        coordinator = subprocess.Popen([sys.executable, "-m", "swarm_cli.coordinator_cmd", f"--trajectory={tmp_path / 'traj.json'}",
                                        "--run=hubgone", f"--hub={hub}", "--no-record", "--json", f"--out={tmp_path}"],
                                       env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        procs.append(coordinator)
        err = ""
        while "config 1/" not in err:
            line = coordinator.stderr.readline()
            assert line, err
            err += line
        router.kill()
        out, rest = coordinator.communicate(timeout=60)
        err += rest
    finally:
        stop_all(procs)
    assert coordinator.returncode == 3, err
    assert "swarm coordinator: error: lost the connection to the hub after step" in err, err
    assert "emergency stop sent" not in err and "lost robot" not in out and "Traceback" not in err, err
    summary = json.loads(out.splitlines()[-1])
    assert summary["lost"] == [] and summary["ended_early"].startswith("lost the connection to the hub")
    assert 1 <= len(summary["configs"]) < 4
