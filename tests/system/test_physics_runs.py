"""A distributed run in the physical world (swarm launch --world physics): recorded, replayed, calibrated."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import uuid
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pymunk")

from runtime.recording.mcap_log import read_messages
from runtime.wire.messages import PhysicsEvent, TruthMessage, decode
from swarm_cli.main import main

REPO = Path(__file__).resolve().parents[2]
ENV = {**os.environ, "PYTHONPATH": str(REPO)}


def swarm(*args, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "swarm_cli.main", *map(str, args)], capture_output=True, text=True, cwd=REPO, env=ENV,
                          timeout=timeout)


def test_a_physics_run_is_recorded_replayed_and_calibrated(tmp_path, capsys):
    """One launch (a real process tree); the replay, export and calibration of its recording in this process."""
    path = tmp_path / "run.mcap"
    proc = swarm("launch", "-n", "4", "--configs", "2", "--method", "no-anchors", "--seed", "4", "--world", "physics",
                 "--run", f"phys{uuid.uuid4().hex[:8]}", "--record", path, "--out", tmp_path / "plots", "--json", timeout=180)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "in the physical world" in proc.stderr
    summary = json.loads(proc.stdout.strip().splitlines()[-1])
    physics, truths = [], {}
    for topic, payload, _, _ in read_messages(path):
        if topic.endswith("/sim/physics"):
            physics.append(decode(payload, PhysicsEvent))
        elif "/sim/truth/" in topic:
            t = decode(payload, TruthMessage)
            truths[t.step, t.robot] = t.pose
    poses = {e.step: e for e in physics if e.kind == "poses"}
    assert sorted(poses) == [1, 2] and all(e.robots == (0, 1, 2, 3) for e in poses.values())
    for step, event in poses.items():  # the agents' truths are the world's poses once it was still, but for a robot that
        # finished its motion and was then pushed by one still moving (a contact): within a body's radius
        got = np.array([truths[step, r] for r in event.robots])
        assert np.all(np.hypot(*(got[:, :2] - np.array(event.poses)[:, :2]).T) < 0.011), (got, event.poses)
    assert summary["pf"] > 0
    assert main(["replay", str(path), "--check"]) == 0  # the coordinator's decisions replay from the recorded inputs, whatever the world
    assert "check passed" in capsys.readouterr().out
    assert main(["export", str(path), "--truth", str(tmp_path / "truth.csv")]) == 0
    capsys.readouterr()
    assert main(["calibrate", str(path), "--truth", str(tmp_path / "truth.csv"), "--out", str(tmp_path / "fitted.toml"), "--json"]) == 0
    fitted = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert fitted["samples"]["drives"] == 8 and 0 < fitted["drive_sigma_frac"] < 0.5
    assert (tmp_path / "fitted.toml").exists()


def test_bench_physics_json_contract_and_bad_input(capsys):
    """``swarm bench physics`` (in this process, one worker): both worlds' rows with the documented keys."""
    assert main(["bench", "physics", "--robots", "4", "--trajectories", "2", "--configs", "1", "--method", "no-anchors",
                 "--workers", "1", "--json"]) == 0
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert (out["trajectories"], out["configs"], out["robots"], out["method"]) == (2, 1, 4, "no-anchors")
    assert [r["world"] for r in out["rows"]] == ["model", "physics"]
    keys = {"world", "pf_mean", "pf_sd", "e_l_mean", "e_l_planned_mean", "contacts_per_100", "stuck_per_100"}
    assert all(set(r) == keys and r["pf_mean"] > 0 for r in out["rows"]) and out["pf_ratio"] > 0
    assert main(["bench", "physics", "--physics-param", "fov_rad=9"]) == 2
    assert "fov_rad must be at most 2 pi" in capsys.readouterr().err

