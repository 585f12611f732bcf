"""A localizer installed as a plugin (an entry point) reaches `swarm sim` in a fresh process and is named in its help."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from tests.integration.test_localizer_registry import write_plugin

REPO = Path(__file__).resolve().parents[2]


def test_an_installed_plugin_reaches_swarm_sim(tmp_path):
    """A package installed with an ``inchworm_swarm.localizers`` entry point: a fresh ``swarm`` process lists it among
    ``--localizer``'s choices and runs the simulation (executor and selection) with it."""
    write_plugin(tmp_path)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), str(REPO)])}
    cmd = [sys.executable, "-m", "swarm_cli.main"]
    helptext = subprocess.run([*cmd, "sim", "--help"], env=env, capture_output=True, text=True, timeout=120, check=True).stdout
    assert "dead-reckoning" in helptext
    out = subprocess.run(
        [*cmd, "sim", "--robots", "6", "--configs", "2", "--localizer", "dead-reckoning", "--samples", "4", "--out", str(tmp_path / "out"), "--json"],
        env=env, capture_output=True, text=True, timeout=300, cwd=tmp_path,
    )
    assert out.returncode == 0, out.stderr
    doc = json.loads(out.stdout.strip().splitlines()[-1])
    assert doc["localizer"] == "dead-reckoning" and [row["n_a"] for row in doc["configs"]] == [0, 0]
    bad = subprocess.run([*cmd, "sim", "--localizer", "kalman"], env=env, capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and "invalid choice: 'kalman'" in bad.stderr and "dead-reckoning" in bad.stderr
