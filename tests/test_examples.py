"""Every script of examples/ runs as a user runs it (subprocesses, small sizes) and does what it says."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def example(name: str, *args: str) -> str:
    out = subprocess.run([sys.executable, str(ROOT / "examples" / name), *args], capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert out.returncode == 0, out.stderr
    return out.stdout


def test_one_run(tmp_path):
    text = example("one_run.py", "--robots", "6", "--configs", "2", "--out", str(tmp_path))
    assert "P_f: inchworm" in text
    assert (tmp_path / "trajectory.png").stat().st_size > 0 and (tmp_path / "errors.png").stat().st_size > 0


def test_table1_small_and_its_resume(tmp_path):
    args = ("--robots", "6", "--trajectories", "2", "--configs", "2", "--out", str(tmp_path))
    text = example("table1_small.py", *args)
    assert "ref57: P_f / ref57 = 1.000" in text and (tmp_path / "pf.png").exists()
    assert example("table1_small.py", *args, "--resume").splitlines()[:-1] == text.splitlines()[:-1]


def test_localize_own_data():
    text = example("localize_own_data.py")
    x1 = float(text.splitlines()[1].split("x ")[1].split(" m")[0])
    assert abs(x1 - 0.4) < 0.01  # robot 1 is 0.4 m ahead of robot 0
    assert "left out robot 17: unobserved" in example("localize_own_data.py", str(ROOT / "docs" / "examples" / "localize-prior.json"))


def test_custom_strategy():
    lines = example("custom_strategy.py", "--robots", "6", "--configs", "2").splitlines()
    assert [line.split(" P_f")[0].strip() for line in lines] == [
        "leaders-first, paper localizer", "ref57, paper localizer", "leaders-first, dead reckoning"]
