"""A localizer installed as a plugin (an entry point) reaches `swarm sim` in a fresh process and is named in its help."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from coordinator.localization.registry import (
    ENTRY_POINT_GROUP,
    register_localizer,
    unregister_localizer,
)

REPO = Path(__file__).resolve().parents[2]
# A small real localizer: dead reckoning only (Phase 1.1), observations ignored.
PLUGIN = textwrap.dedent('''
    """Dead reckoning only: the post-step estimate is the commands replayed on the prior (Eq. 17-19)."""

    from coordinator.localization.dead_reckoning import dead_reckon
    from runtime.errors import LocalizationError


    class DeadReckoningLocalizer:
        name = "dead-reckoning"

        def __init__(self, cfg, inflate=1.0):
            self.cfg, self.inflate = cfg, inflate  # inflate: factor on the reported covariance

        def localize(self, prior, step, obs):
            est = dead_reckon(prior, step, self.cfg)
            return type(est)(est.ids, est.poses, est.cov * self.inflate)

        def localize_subset(self, prior, step, obs, keep):
            return self.localize(prior, step, obs)

        def topology(self, ids, obs, initial_poses=None):
            raise LocalizationError("unobserved", ids, "dead reckoning estimates no topology")
''')


def write_plugin(folder: Path) -> None:
    """``dr_plugin`` as an installed distribution on ``folder``: the module and a dist-info with its entry point."""
    (folder / "dr_plugin.py").write_text(PLUGIN)
    info = folder / "dr_plugin-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: dr-plugin\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(f"[{ENTRY_POINT_GROUP}]\ndead-reckoning = dr_plugin:DeadReckoningLocalizer\n")


@pytest.fixture
def dead_reckoning(tmp_path, monkeypatch):
    """The plugin importable in this process, registered in code as ``dr`` for the test."""
    write_plugin(tmp_path)
    monkeypatch.syspath_prepend(str(tmp_path))
    from dr_plugin import DeadReckoningLocalizer  # written by the fixture

    register_localizer("dr", DeadReckoningLocalizer)
    yield DeadReckoningLocalizer
    unregister_localizer("dr")
    sys.modules.pop("dr_plugin", None)


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
