"""``swarm sim`` and ``swarm compare`` as a user runs them (real subprocesses, small sizes)."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def swarm(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "swarm_cli.main", *args], capture_output=True, text=True, timeout=300, cwd=ROOT)


def test_sim_writes_plots_csv_and_json(tmp_path):
    out = swarm("sim", "--robots", "6", "--configs", "2", "--samples", "4", "--generations", "2", "--out", str(tmp_path), "--json")
    assert out.returncode == 0, out.stderr
    doc = json.loads(out.stdout.strip().splitlines()[-1])
    rows = doc["configs"]
    assert doc["method"] == "inchworm" and [r["config"] for r in rows] == [1, 2]
    # P_f (Eq. 24) = final following error / average total motion (Eq. 25), both in its own table
    assert doc["pf"] == pytest.approx(rows[-1]["following_error"] / rows[-1]["travelled"], rel=1e-12)
    assert 0 < rows[0]["travelled"] < rows[1]["travelled"]  # partial sums of Eq. 25
    legs = {leg["config"]: leg for leg in doc["legs"]}  # configurations whose drives ended too close: approach legs
    for r in rows:
        planned = 6 // (6 - r["n_a"])  # Eq. 7 for 6 robots
        assert r["n_a"] in (0, 3, 4, 5) and (r["steps"] > planned == 1 and legs[r["config"]]["steps"] == r["steps"]
                                             if r["config"] in legs else r["steps"] == planned)
    assert doc["steps_added"] == sum(r["steps"] - 6 // (6 - r["n_a"]) for r in rows)
    for name in ("trajectory.png", "errors.png", "configs.csv"):
        assert (tmp_path / name).stat().st_size > 0


def test_sim_rejects_a_disconnected_trajectory(tmp_path):
    path = tmp_path / "t.json"
    path.write_text(json.dumps({"robots": [0, 1], "initial_poses": [[0, 0, 0], [0.2, 0, 0]], "configurations": [[[0, 0], [3, 0]]]}))
    out = swarm("sim", "--trajectory", str(path), "--out", str(tmp_path))
    assert out.returncode == 2
    assert "configuration 1 is not connected" in out.stderr and "Traceback" not in out.stderr


def test_compare_json_contract(tmp_path):
    out = swarm("compare", "--robots", "6", "--trajectories", "2", "--configs", "2", "--methods", "ref57,no-anchors,heuristic-fixed",
                "--workers", "1", "--robot-radius", "0", "--out", str(tmp_path), "--json")  # point robots: no step split for bodies
    assert out.returncode == 0, out.stderr
    doc = json.loads(out.stdout.strip().splitlines()[-1])
    assert set(doc["methods"]) == {"ref57", "no-anchors", "heuristic-fixed"}
    for stats in doc["methods"].values():
        assert {"pf_mean", "pf_std", "na_mean", "steps_mean"} <= set(stats)
    assert doc["methods"]["ref57"]["na_mean"] == 3 and doc["methods"]["no-anchors"]["steps_mean"] == 1
    assert set(doc["p_values"]) == {"no-anchors", "heuristic-fixed"}
    assert (tmp_path / "runs.csv").exists() and (tmp_path / "pf.png").exists()
    assert doc["methods"]["ref57"]["na_by_config"] == [3.0, 3.0]  # n_a along the trajectory, per configuration index
    runs = list(csv.DictReader(open(tmp_path / "runs.csv")))
    for m, stats in doc["methods"].items():  # drift: final e_l as a percentage of the distance travelled
        drifts = [float(r["drift_pct"]) for r in runs if r["method"] == m]
        assert stats["drift_pct_mean"] == pytest.approx(sum(drifts) / len(drifts)) and 0 < stats["drift_pct_mean"] < 100
    assert "mc-start = \"known\"" in (tmp_path / "study.toml").read_text()  # the default reading, recorded with the options


def test_sim_records_the_monte_carlo_reading(tmp_path):
    out = swarm("sim", "--robots", "6", "--configs", "1", "--samples", "2", "--generations", "1", "--mc-start", "known",
                "--mc-emax", "worst", "--out", str(tmp_path), "--json")
    assert out.returncode == 0, out.stderr
    doc = json.loads(out.stdout.strip().splitlines()[-1])
    assert (doc["mc_start"], doc["mc_emax"]) == ("known", "worst")


def test_worst_emax_needs_the_monte_carlo(tmp_path):
    out = swarm("sim", "--robots", "6", "--configs", "1", "--selection", "crlb", "--mc-emax", "worst", "--out", str(tmp_path))
    assert out.returncode == 2 and "Traceback" not in out.stderr
    assert out.stderr.strip().splitlines()[-1].endswith("use it with the mc selection, not crlb")


def test_compare_rejects_unknown_methods():
    out = swarm("compare", "--methods", "inchworm,teleport")
    assert out.returncode == 2 and "--methods must list names among" in out.stderr and "unknown: ['teleport']" in out.stderr


def test_sim_of_an_odd_swarm_compares_with_no_anchors(tmp_path):
    """ref57 cannot halve 5 robots: the default baseline becomes no-anchors; asking for ref57 fails before any run."""
    out = swarm("sim", "--robots", "5", "--configs", "2", "--samples", "4", "--generations", "2", "--out", str(tmp_path), "--json")
    assert out.returncode == 0, out.stderr
    assert "sim no-anchors" in out.stderr + out.stdout
    refused = swarm("sim", "--robots", "5", "--configs", "2", "--baseline", "ref57", "--out", str(tmp_path / "r"))
    assert refused.returncode == 2 and "Traceback" not in refused.stderr
    assert "--baseline ref57 uses n_a = n_r / 2 and needs an even number of robots, got 5" in refused.stderr
    assert not (tmp_path / "r" / "configs.csv").exists()
