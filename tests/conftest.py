"""Test levels, shared fixtures (noise-free and default model configurations).

Tests sit in one folder per level, and the folder is the only declaration of a test's level:

* ``tests/unit``: one process, no network session, no subprocess: the maths, the codecs, the parsers;
* ``tests/integration``: still one process, with real Zenoh sessions, MCAP files, servers, whole runs and
  studies in-process;
* ``tests/system``: real processes and signals: the ``swarm`` commands as subprocesses, agents, links,
  coordinators, routers, emulators on ptys, ROS 2 participants.

Each test gets the marker of its level; ``slow`` marks integration and system tests, so
``python -m pytest -m "not slow"`` (or ``python -m pytest tests/unit``) is the quick subset and
``python -m pytest`` runs everything. Helper modules shared by several levels (``agent_hub``,
``fault_drivers``, ``localize_cases``, ``waiting``) sit in ``tests/`` itself, which is on ``sys.path`` (pyproject's ``pythonpath``).
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

import pytest
from hypothesis import HealthCheck, settings

from runtime.models.config import ModelConfig
from runtime.wire.run_file import ENV_DIR

# Behaviour, not speed: no per-example deadline and no "input generation is slow" failure
# (a busy 2-core machine can stall any draw for a second).
settings.register_profile("behaviour", deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.load_profile("behaviour")

LEVELS = ("unit", "integration", "system")
_made_run_dir: list[str] = []  # the run-file folder pytest_configure made in this process


def pytest_configure(config: pytest.Config) -> None:
    """Under ``PYTHONDONTWRITEBYTECODE`` every process a test starts (agents, coordinators, ``swarm`` commands: more
    than a thousand in a run of the suite) compiled the project's modules again, 0.08 s of CPU per agent and 0.17 s
    per coordinator: their bytecode is cached outside the source tree instead (``PYTHONPYCACHEPREFIX``, a folder
    under the temporary directory that the workers share and later runs reuse), so nothing is written next to the
    sources either way."""
    if os.environ.get("PYTHONDONTWRITEBYTECODE") and not os.environ.get("PYTHONPYCACHEPREFIX"):
        os.environ.pop("PYTHONDONTWRITEBYTECODE")
        os.environ["PYTHONPYCACHEPREFIX"] = str(Path(tempfile.gettempdir()) / f"inchworm-swarm-tests-pycache-{os.getuid()}")
    if not os.environ.get(ENV_DIR) or os.environ.get("PYTEST_XDIST_WORKER"):
        # The run files of the launches of this process's tests (``runtime.wire.run_file``) in a folder of its own (a worker
        # too, not its controller's): a run id that another worker or another run of the suite on this host had live was
        # refused ("that run is already live").
        _made_run_dir.append(tempfile.mkdtemp(prefix="inchworm-swarm-tests-runs-"))
        os.environ[ENV_DIR] = _made_run_dir[0]


def pytest_unconfigure(config: pytest.Config) -> None:
    """Remove the run-file folder ``pytest_configure`` made."""
    while _made_run_dir:
        os.environ.pop(ENV_DIR, None)
        shutil.rmtree(_made_run_dir.pop(), ignore_errors=True)


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Mark each test with its folder's level, and integration and system tests as ``slow`` (module docstring)."""
    for item in items:
        level = item.path.parent.name
        if level not in LEVELS:
            raise pytest.UsageError(f"{item.path}: a test module belongs in tests/unit, tests/integration or tests/system")
        item.add_marker(getattr(pytest.mark, level))
        if level != "unit":
            item.add_marker(pytest.mark.slow)


@pytest.fixture
def cfg() -> ModelConfig:
    return ModelConfig()


@pytest.fixture
def exact_sensing() -> ModelConfig:
    """Default motion noise, noise-free sensing."""
    return ModelConfig(range_sigma_m=0.0, bearing_sigma_rad=0.0)
