"""`swarm study consistency` as a user runs it: its --json contract and its one-line errors."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_study_consistency_json_contract(tmp_path):
    out = subprocess.run(
        [sys.executable, "-m", "swarm_cli.main", "study", "consistency", "--configs", "2", "--trajectories", "1",
         "--robots", "6", "--methods", "no-anchors,ref57", "--motion-scales", "1,2", "--out", str(tmp_path), "--json"],
        capture_output=True, text=True, timeout=600, cwd=ROOT,
    )
    assert out.returncode == 0, out.stderr
    doc = json.loads(out.stdout.strip().splitlines()[-1])
    assert list(doc) == ["rows"]
    assert [(r["motion_scale"], r["sensing_scale"], r["localizer"], r["method"]) for r in doc["rows"]] == [
        (m, 1.0, loc, method) for m in (1.0, 2.0) for loc in ("paper", "joint") for method in ("no-anchors", "ref57")]
    for r in doc["rows"]:
        assert list(r) == ["localizer", "method", "configs", "nees_over_expected_median", "nees_over_expected_max",
                           "nees_over_expected_min", "nees_over_expected_p95", "motion_scale", "sensing_scale"]
        assert r["configs"] == 2 and 0 < r["nees_over_expected_min"] <= r["nees_over_expected_median"] <= r["nees_over_expected_max"]
        assert r["nees_over_expected_median"] <= r["nees_over_expected_p95"] <= r["nees_over_expected_max"]
    assert (tmp_path / "consistency.png").stat().st_size > 0
    bad = subprocess.run([sys.executable, "-m", "swarm_cli.main", "study", "consistency", "--methods", "nope"],
                         capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert bad.returncode == 2 and "--methods" in bad.stderr and "Traceback" not in bad.stderr
    bad = subprocess.run([sys.executable, "-m", "swarm_cli.main", "study", "consistency", "--sensing-scales", "1,-4"],
                         capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert bad.returncode == 2 and "--sensing-scales" in bad.stderr and "Traceback" not in bad.stderr
