"""Bodies through the user's options: ``--robot-radius``, trajectories that cannot be made, ``swarm bench collisions``
(real subprocesses, small sizes)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def swarm(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "swarm_cli.main", *args], capture_output=True, text=True, timeout=300, cwd=ROOT)


def write(path: Path, initial: list, configs: list) -> Path:
    path.write_text(json.dumps({"robots": list(range(len(initial))), "initial_poses": initial, "configurations": configs}))
    return path


def test_a_swap_in_a_tight_spot_is_refused_naming_the_configuration_and_robots(tmp_path):
    traj = write(tmp_path / "swap.json", [[0, 0, 0], [0.03, 0, 0], [0, 0.2, 0]],
                 [[[0.0, 0.1], [0.03, 0.1], [0.0, 0.3]], [[0.03, 0.1], [0.0, 0.1], [0.0, 0.3]]])
    out = swarm("sim", "--trajectory", str(traj), "--out", str(tmp_path))
    assert out.returncode == 2 and "Traceback" not in out.stderr
    assert "configuration 2: robots 0 and 1 cannot reach it without touching" in out.stderr
    points = swarm("sim", "--trajectory", str(traj), "--robot-radius", "0", "--method", "no-anchors", "--baseline", "none",
                   "--out", str(tmp_path))
    assert points.returncode == 0, points.stderr  # the paper's point robots pass through each other


def test_overlapping_robots_and_a_negative_radius_are_refused(tmp_path):
    traj = write(tmp_path / "overlap.json", [[0, 0, 0], [0.1, 0, 0]], [[[0.0, 0.0], [0.02, 0.0]]])
    out = swarm("sim", "--trajectory", str(traj), "--out", str(tmp_path))
    assert out.returncode == 2 and "configuration 1: robots 0 and 1 overlap: centres 0.0200 m apart" in out.stderr
    bad = swarm("sim", "--robot-radius", "-0.01", "--out", str(tmp_path))
    assert bad.returncode == 2 and "argument --robot-radius: must be >= 0" in bad.stderr


def test_a_mover_crossing_an_anchor_is_regrouped_and_reported(tmp_path):
    traj = write(tmp_path / "cross.json", [[0, 0, 0], [0.15, 0, 1], [0, 0.3, 0], [0.3, 0.3, 0]],
                 [[[0.3, 0.0], [0.15, 0.12], [0.0, 0.32], [0.3, 0.32]]])
    out = swarm("sim", "--trajectory", str(traj), "--method", "ref57", "--seed", "3", "--out", str(tmp_path), "--json")
    assert out.returncode == 0, out.stderr
    doc = json.loads(out.stdout.strip().splitlines()[-1])
    assert doc["robot_radius_m"] == 0.011 and doc["contacts"] == [] and doc["steps_added"] >= 1
    assert doc["configs"][0]["steps"] == 2 + doc["steps_added"] and "config 1: steps split for bodies: 2 -> " in out.stdout
    [split] = doc["regrouped"]  # how the chance constraint split the plan (an addition to the --json)
    assert split == {"config": 1, "planned_steps": 2, "steps": 2 + doc["steps_added"], "contact_bound": 0.001, "unclear": []}
    points = swarm("sim", "--trajectory", str(traj), "--method", "ref57", "--seed", "3", "--robot-radius", "0", "--out", str(tmp_path), "--json")
    doc = json.loads(points.stdout.strip().splitlines()[-1])
    assert doc["robot_radius_m"] == 0 and doc["steps_added"] == 0 and doc["configs"][0]["steps"] == 2


def test_radius_zero_prints_the_numbers_of_the_point_robots(tmp_path):
    # P_f printed by the code before bodies (main at 9d1f4c4) for `swarm sim --configs 3 --seed 1 --samples 4 --json`;
    # its last bits follow the CPU's BLAS kernels (runtime.recording.mcap_log.float_platform): equal to 1e-12 relative
    out = swarm("sim", "--configs", "3", "--seed", "1", "--samples", "4", "--robot-radius", "0", "--out", str(tmp_path), "--json")
    assert out.returncode == 0, out.stderr
    assert json.loads(out.stdout.strip().splitlines()[-1])["pf"] == pytest.approx(0.03683147182078007, rel=1e-12, abs=0)


def test_bench_collisions_json_contract():
    out = swarm("bench", "collisions", "--trajectories", "2", "--configs", "2", "--methods", "ref57,one-at-a-time", "--workers", "1",
                "--noise-scales", "1,3", "--json")
    assert out.returncode == 0, out.stderr
    doc = json.loads(out.stdout.strip().splitlines()[-1])
    assert list(doc) == ["radius_m", "trajectories", "configs", "rows"]
    assert (doc["radius_m"], doc["trajectories"], doc["configs"]) == (0.011, 2, 2)
    assert [(r["noise_scale"], r["method"], r["localizer"], r["bodies"]) for r in doc["rows"]] == [
        (k, m, "paper", b) for k in (1.0, 3.0) for m in ("ref57", "one-at-a-time") for b in (True, False)]
    for row in doc["rows"]:
        assert list(row) == ["method", "localizer", "bodies", "contacts_per_100", "configs_with_contact_pct", "steps_per_config", "pf_mean",
                             "noise_scale", "steps_added", "unclear_changes", "raised_bound_changes", "leg_changes",
                             "staging_stops", "stopped_short", "stopped_short_changes", "holds", "corrections", "legs_cut",
                             "deferred"]  # the last eleven: additions
        assert row["unclear_changes"] <= row["raised_bound_changes"] <= 2 * 2 and (row["bodies"] or row["steps_added"] == 0)
        legged = row["staging_stops"] + row["stopped_short"] + row["holds"] + row["legs_cut"] + row["deferred"] > 0
        assert row["leg_changes"] <= 2 * 2 and (row["leg_changes"] > 0) == legged
        assert row["bodies"] or row["leg_changes"] + row["holds"] + row["corrections"] + row["legs_cut"] + row["deferred"] == 0
        assert row["stopped_short_changes"] <= min(row["stopped_short"], 2 * 2)
        assert row["contacts_per_100"] >= row["configs_with_contact_pct"] >= 0 and row["pf_mean"] > 0
    by = {(r["method"], r["bodies"], r["noise_scale"]): r for r in doc["rows"]}
    for k in (1.0, 3.0):
        assert by[("ref57", True, k)]["steps_per_config"] >= by[("ref57", False, k)]["steps_per_config"] == 2
        single = by[("one-at-a-time", True, k)]  # one robot a step; approach legs add steps of their own
        assert single["steps_per_config"] == 10 + single["steps_added"] / 4 and by[("one-at-a-time", False, k)]["steps_per_config"] == 10
    assert by[("ref57", False, 3.0)]["pf_mean"] > by[("ref57", False, 1.0)]["pf_mean"]  # three times the motion noise
    bad = swarm("bench", "collisions", "--robot-radius", "0")
    assert bad.returncode == 2 and "--robot-radius must be > 0" in bad.stderr
    bad = swarm("bench", "collisions", "--noise-scales", "1,x")
    assert bad.returncode == 2 and "--noise-scales must be comma-separated numbers" in bad.stderr and "Traceback" not in bad.stderr


def test_a_gateway_whose_robots_have_other_bodies_is_refused_before_anything_starts(tmp_path):
    config = tmp_path / "gw.json"
    config.write_text(json.dumps({"ports": [{"name": "radio0", "device": "/dev/null", "robots": list(range(10))}],
                                  "limits": {"robot_radius_m": 0.02}}))
    out = swarm("demo", "--driver", "gateway", "--gateway-config", str(config), "--no-record", "--out", str(tmp_path))
    assert out.returncode == 2 and "Traceback" not in out.stderr
    assert "--robot-radius 0.011 (of the model) differs from the robots' body radius 0.02 m" in out.stderr
    config.write_text(json.dumps({"ports": [{"name": "radio0", "device": "/dev/null", "robots": [0]}], "limits": {"robot_radius_m": -1}}))
    out = swarm("demo", "--driver", "gateway", "--gateway-config", str(config), "--no-record", "--out", str(tmp_path))
    assert out.returncode == 2 and "limits.robot_radius_m: must be >= 0, got -1" in out.stderr
