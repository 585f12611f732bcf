"""The localizer registry: a localizer a user registers (in code or as an installed plugin) reaches ``swarm sim``,
the executor and the planner's Monte Carlo; the planner simulates the executor's localizer object, options included."""

from __future__ import annotations

import json
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from coordinator.executor import InchwormExecutor
from coordinator.localization import make_localizer
from coordinator.localization.registry import (
    BUILTIN_LOCALIZERS,
    ENTRY_POINT_GROUP,
    localizer_names,
    register_localizer,
    unregister_localizer,
)
from coordinator.plan import Plan
from coordinator.selection.monte_carlo import MonteCarlo
from coordinator.selection.selector import SelectionConfig
from coordinator.strategies import make_strategy
from runtime.errors import SwarmInputError
from runtime.models.config import ModelConfig
from runtime.models.simulation import SimulatedSwarm
from runtime.models.state import SwarmEstimate
from runtime.models.trajectory import random_trajectory
from swarm_cli.main import main

CFG = ModelConfig()

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


def scene(n: int = 6, seed: int = 3) -> tuple[SwarmEstimate, np.ndarray, list[Plan]]:
    traj = random_trajectory(n, 1, np.random.default_rng(seed), sensing_range=CFG.sensing_range_m)
    estimate = SwarmEstimate.isotropic(traj.ids, traj.initial_poses, 0.01, np.radians(2.0))
    rng = np.random.default_rng(seed)
    plans = [Plan.equal(rng.permutation(n), n // 2) for _ in range(4)]  # the same step count, as the Monte Carlo asks
    return estimate, traj.configurations[0], plans


def test_names_and_bad_input():
    assert localizer_names()[:2] == BUILTIN_LOCALIZERS == ("paper", "joint")
    with pytest.raises(SwarmInputError, match="unknown localizer 'kalman'; choose one of paper, joint"):
        make_localizer("kalman", CFG)
    with pytest.raises(SwarmInputError, match="does not take options"):
        make_localizer("paper", CFG, gauge=True)
    with pytest.raises(SwarmInputError, match="built in"):
        register_localizer("joint", lambda cfg: None)
    with pytest.raises(SwarmInputError, match="without commas"):
        register_localizer("a,b", lambda cfg: None)
    assert make_localizer("joint", CFG, huber=2.5, constrain_gauge=False).huber == 2.5


def test_a_registered_localizer_drives_the_monte_carlo(dead_reckoning):
    """With dead reckoning only, anchors cannot help: every robot moves once, on the same common random
    numbers whatever the plan, and nobody's estimate uses anyone else's, so e_l is the same for every plan;
    the paper's localizer, on the same numbers, tells the plans apart."""
    estimate, desired, plans = scene()
    loc = make_localizer("dr", CFG)
    assert isinstance(loc, dead_reckoning) and "dr" in localizer_names()
    e_dr = MonteCarlo(CFG, loc, 8, seed=5).localization_errors(estimate, desired, plans)
    np.testing.assert_allclose(e_dr, e_dr[0], rtol=1e-12)
    e_paper = MonteCarlo(CFG, make_localizer("paper", CFG), 8, seed=5).localization_errors(estimate, desired, plans)
    assert np.ptp(e_paper) > 1e-4 and not np.allclose(e_paper, e_dr)
    assert e_paper[1:].min() < e_dr[0]  # anchors and observations beat dead reckoning


def test_a_registered_localizer_runs_swarm_sim_in_process(dead_reckoning, tmp_path, capsys):
    """``swarm sim --localizer dr``: its parser lists the registered name; the executor and the selection both use
    it (selection: every plan scores the same e_l, so the fastest, n_a = 0, wins every configuration)."""
    code = main(["sim", "--robots", "6", "--configs", "2", "--localizer", "dr", "--samples", "4", "--out", str(tmp_path), "--json"])
    assert code == 0
    doc = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert doc["localizer"] == "dr" and [row["n_a"] for row in doc["configs"]] == [0, 0]
    assert np.isfinite(doc["pf"])


def test_a_registered_localizer_runs_a_study(dead_reckoning, tmp_path, capsys):
    """``swarm study consistency --localizers paper,dr``: the study's list reads the registry. Dead reckoning with
    its honest covariance (the motion noise propagated, ``inflate`` 1) differs from the paper's fused estimate."""
    code = main(["study", "consistency", "--localizers", "paper,dr", "--methods", "no-anchors", "--robots", "4", "--configs", "2",
                 "--trajectories", "2", "--out", str(tmp_path), "--json"])
    assert code == 0
    rows = json.loads(capsys.readouterr().out.strip().splitlines()[-1])["rows"]
    assert [r["localizer"] for r in rows] == ["paper", "dr"]
    assert rows[0]["nees_over_expected_median"] != rows[1]["nees_over_expected_median"]
    assert main(["study", "consistency", "--localizers", "paper,kalman", "--out", str(tmp_path)]) == 2


def test_the_executor_and_the_planner_share_one_localizer_object(dead_reckoning):
    loc = make_localizer("paper", CFG, huber=0.02)
    traj = random_trajectory(6, 1, np.random.default_rng(1), sensing_range=CFG.sensing_range_m)
    strategy = make_strategy("inchworm", traj.n, CFG, loc, SelectionConfig(samples=2), seed=0)
    executor = InchwormExecutor(SimulatedSwarm(traj.ids, traj.initial_poses, CFG, 0), loc, strategy, CFG)
    assert executor.localizer is strategy.selector.localizer is loc


@pytest.mark.parametrize(("name", "huber"), [("paper", 0.004), ("joint", 0.5)])
def test_an_option_of_the_executors_localizer_changes_the_monte_carlo(name, huber):
    """A Huber loss set on the localizer object reaches the planner: the Monte Carlo localizes every sample
    through that localizer (``partial.localize_observable``), so e_l changes; a threshold nothing reaches
    (1e6) gives back the plain least squares of the vectorised path, to rounding."""
    estimate, desired, plans = scene(n=6, seed=4)
    cfg = ModelConfig(range_sigma_m=0.02, bearing_sigma_rad=np.radians(4.0))

    def e_l(**options) -> np.ndarray:
        return MonteCarlo(cfg, make_localizer(name, cfg, **options), 6, seed=2).localization_errors(estimate, desired, plans)

    plain, robust, neutral = e_l(), e_l(huber=huber), e_l(huber=1e6)
    assert np.abs(robust - plain).max() > 1e-5
    np.testing.assert_allclose(neutral, plain, rtol=1e-7)


