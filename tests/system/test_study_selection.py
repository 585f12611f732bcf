"""``swarm study selection`` and ``swarm study calibration`` as a user runs them (real subprocesses, tiny sizes)."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np

from coordinator.plan import enumerate_plans, n_solutions

ROOT = Path(__file__).resolve().parents[2]


def swarm(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "swarm_cli.main", *args], capture_output=True, text=True, timeout=600, cwd=ROOT)


def test_enumeration_is_every_ordered_partition_once():
    for n, n_a in ((6, 3), (6, 4), (8, 4)):
        plans = enumerate_plans(n, n_a)
        assert len(plans) == n_solutions(n, n_a) == len({p.key() for p in plans})


def test_study_selection_json_contract(tmp_path):
    # point robots: at this size the chance constraint of bodies leaves the searched counts without a clear plan, so the
    # ratios would be null (docs/selection.md)
    out = swarm("study", "selection", "--robots", "6", "--configs", "2", "--screen-samples", "4", "--pick-samples", "8",
                "--eval-samples", "16", "--workers", "1", "--robot-radius", "0", "--out", str(tmp_path), "--json")
    assert out.returncode == 0, out.stderr
    last = json.loads(out.stdout.strip().splitlines()[-1])
    assert list(last) == ["ga_over_optimum_median", "ga_over_optimum_max", "heuristic_over_optimum_median", "na_agrees", "configs",
                          "search_vs_heuristic", "search_missing", "na_within_noise"]
    assert last["na_agrees"] <= last["na_within_noise"] <= last["configs"]
    assert last["search_missing"] == 0  # the search returned a clear plan wherever the enumeration found one
    for v in last["search_vs_heuristic"].values():  # per count: how often the search returned or beat its seed
        assert v["cases"] == 2 and 0 <= v["seed_returned"] <= 2 and v["beats"] + v["loses"] <= 2
        if v["seed_returned"] == 2:  # the seed itself: no difference to beat or lose
            assert v["beats"] == v["loses"] == 0
    assert last["configs"] == 2 and 0 <= last["na_agrees"] <= 2
    # the optimum is picked on other samples than the ratios are computed on: ratios near 1, possibly below
    assert 0.8 < last["ga_over_optimum_median"] <= last["ga_over_optimum_max"] < 1.5
    again = swarm("study", "selection", "--robots", "6", "--from-csv", str(tmp_path / "configs.csv"), "--json")
    assert again.returncode == 0, again.stderr
    assert json.loads(again.stdout.strip().splitlines()[-1]) == last  # the CSV keeps everything the summary needs


def test_genetic_gain_json_contract():
    out = swarm("study", "selection", "--genetic-gain", "--robots", "6", "--configs", "2", "--eval-samples", "8", "--robot-radius", "0", "--json")
    assert out.returncode == 0, out.stderr
    last = json.loads(out.stdout.strip().splitlines()[-1])
    assert last["robots"] == 6 and last["configs"] == 2 and last["localizer"] == "paper" and last["robot_radius_m"] == 0
    assert set(last["counts"]) == {"3", "4", "5"}  # every count n_a > 0 with at most 10 steps (Eq. 7)
    for c in last["counts"].values():
        assert c["cases"] == 2 and c["beats"] + c["loses"] <= c["replaced"] <= c["cases"] - c["no_seed"] and c["search_s_median"] > 0
    assert last["cases"] == 6 and last["beats"] == sum(c["beats"] for c in last["counts"].values())
    assert "beats its seed in" in out.stdout


def test_study_calibration_finds_the_noise_and_pairs_the_seed_sets(tmp_path):
    out = swarm("study", "calibration", "--localizers", "paper", "--trajectories", "2", "--configs", "2",
                "--calibration-trajectories", "2", "--iterations", "3", "--seeds", "0,1000", "--methods", "no-anchors,ref57",
                "--workers", "1", "--out", str(tmp_path), "--json")
    assert out.returncode == 0, out.stderr
    result = json.loads(out.stdout.strip().splitlines()[-1])["results"][0]
    assert 1.0 < result["motion_scale"] < 32.0
    assert set(result) >= {"0", "1000", "pooled"} and result["pooled"]["trajectories"] == 4
    pooled = result["pooled"]["pf"]
    per_set = [result[s]["pf"] for s in ("0", "1000")]
    for m in ("no-anchors", "ref57"):  # pooled means are the means of the two equal-sized sets
        assert math.isclose(pooled[m], np.mean([p[m] for p in per_set]), rel_tol=1e-9)
    assert result["pooled"]["na_by_config"] == {"no-anchors": [0.0, 0.0], "ref57": [5.0, 5.0]}  # n_a along the trajectory
    assert all(0 < v < 100 for v in result["pooled"]["drift_pct"].values())


def test_bad_options_are_named():
    out = swarm("study", "selection", "--configs", "0")
    assert out.returncode != 0 and "--configs" in out.stderr and "Traceback" not in out.stderr
    out = swarm("sim", "--genetic", "sometimes")
    assert out.returncode == 2 and "--genetic" in out.stderr and "Traceback" not in out.stderr
    out = swarm("compare", "--selections", "mc,bogus")
    assert out.returncode != 0 and "--selections" in out.stderr and "Traceback" not in out.stderr
