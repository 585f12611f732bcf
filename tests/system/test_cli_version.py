"""``swarm --version``: the installed distribution's version, and a ``--help`` that does not pay for it."""

from __future__ import annotations

import os
import subprocess
import sys
import tomllib
from importlib.metadata import version
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
ENV = {**os.environ, "PYTHONPATH": str(REPO)}


def _swarm(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "swarm_cli.main", *args], capture_output=True, text=True, env=ENV, timeout=60)


def test_version_prints_the_installed_version_and_exits_0() -> None:
    done = _swarm("--version")
    assert done.returncode == 0, done.stderr
    assert done.stdout == f"swarm {version('inchworm-swarm')}\n"
    assert done.stderr == ""


def test_the_installed_version_is_the_one_pyproject_declares() -> None:
    declared = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["version"]
    assert _swarm("--version").stdout.split() == ["swarm", declared]


def test_version_wins_over_a_missing_command_and_is_listed_in_help() -> None:
    assert _swarm("--version", "sim").stdout.startswith("swarm ")
    assert "--version" in _swarm("--help").stdout


def test_help_does_not_import_the_metadata_reader() -> None:
    code = ("import sys\nfrom swarm_cli.main import main\ntry:\n    main(['--help'])\nexcept SystemExit:\n    pass\n"
            "print('importlib.metadata' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=ENV, check=True).stdout
    assert out.splitlines()[-1] == "False"
