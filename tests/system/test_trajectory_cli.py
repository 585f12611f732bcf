"""`swarm sim` names a bad robot count instead of hanging (a subprocess)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("robots", ["1", "0", "-2"])
def test_sim_names_a_bad_robot_count_instead_of_hanging(robots, tmp_path):
    proc = subprocess.run([sys.executable, "-m", "swarm_cli.main", "sim", f"--robots={robots}", "--out", str(tmp_path)],
                          capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert proc.returncode == 2
    assert f"--robots must be >= 2 for a random trajectory, got {robots}" in proc.stderr
    assert "Traceback" not in proc.stderr


