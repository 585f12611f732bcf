"""Readings of the selection's Monte Carlo: where it starts (estimate / known) and what e_l,max is (mean / worst)."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from coordinator.localization import make_localizer
from coordinator.plan import Plan, enumerate_plans
from coordinator.replay_check import RecordedRun, recorded_selection
from coordinator.selection.genetic import GeneticConfig
from coordinator.selection.monte_carlo import MonteCarlo
from coordinator.selection.selector import AnchorSelector, SelectionConfig
from runtime.errors import SwarmInputError
from runtime.models.config import ModelConfig
from runtime.models.state import SwarmEstimate
from runtime.models.trajectory import random_trajectory

NOISELESS = replace(ModelConfig(), turn_sigma_rad=0.0, drive_sigma_frac=0.0, range_sigma_m=0.0, bearing_sigma_rad=0.0)


def step_problem(n: int, seed: int, sigma: float = 0.02) -> tuple[SwarmEstimate, np.ndarray]:
    traj = random_trajectory(n, 1, np.random.default_rng(seed))
    return SwarmEstimate.isotropic(traj.ids, traj.initial_poses, sigma, math.radians(3)), traj.configurations[0]


@pytest.mark.parametrize("localizer", ["paper", "joint"])
def test_known_start_without_noise_has_no_error(localizer):
    estimate, desired = step_problem(6, 0)
    plans = [Plan.equal(np.arange(6), 0), *enumerate_plans(6, 3)[:2]]
    known = MonteCarlo(NOISELESS, make_localizer(localizer, NOISELESS), 5, seed=3, start="known").localization_errors(
        estimate, desired, plans, per_sample=True)
    drawn = MonteCarlo(NOISELESS, make_localizer(localizer, NOISELESS), 5, seed=3, start="estimate").localization_errors(
        estimate, desired, plans, per_sample=True)
    if localizer == "paper":
        np.testing.assert_allclose(known, 0.0, atol=1e-9)
    else:  # its dead reckoning is the motion's mean given the estimate's 3 deg heading uncertainty, d exp(-s^2 / 2) along
        # the commanded heading, which the truth (moved exactly as commanded) is not: at most d (1 - exp(-s^2 / 2)) off
        drive = np.linalg.norm(desired - estimate.poses[:, :2], axis=1).max()
        assert np.all(known < drive * -np.expm1(-estimate.cov[0, 2, 2] / 2))
    assert np.all(drawn > 1e-3)  # the estimate's 2 cm uncertainty is in every drawn start


def test_known_start_scores_only_the_added_error():
    """With noise, a known start's e_l is below the drawn start's (which carries the error before the change)."""
    estimate, desired = step_problem(10, 1, sigma=0.05)
    plans = [Plan.equal(np.arange(10), 0)]
    known = MonteCarlo(ModelConfig(), make_localizer("joint", ModelConfig()), 32, seed=4, start="known").localization_errors(
        estimate, desired, plans)[0]
    drawn = MonteCarlo(ModelConfig(), make_localizer("joint", ModelConfig()), 32, seed=4, start="estimate").localization_errors(
        estimate, desired, plans)[0]
    assert 0 < known < 0.5 * drawn


def test_worst_emax_is_at_least_the_mean():
    estimate, desired = step_problem(8, 2)
    base = SelectionConfig(samples=6, genetic=GeneticConfig(population=4, generations=1), final_samples=16)
    mean = AnchorSelector(ModelConfig(), make_localizer("paper", ModelConfig()), base, seed=7).select(estimate, desired)
    worst = AnchorSelector(ModelConfig(), make_localizer("paper", ModelConfig()), replace(base, mc_emax="worst"), seed=7).select(estimate, desired)
    p_mean = {s.n_anchors: s for s in mean.scores if s.plan is not None}
    p_worst = {s.n_anchors: s for s in worst.scores if s.plan is not None}
    assert p_mean[0].p_l == pytest.approx(1.0)
    assert 0 < p_worst[0].p_l < 1.0  # e_l(0) over its largest sample
    for n_a in set(p_mean) & set(p_worst):  # same samples: only the denominator differs where not searched
        if not (p_mean[n_a].searched or p_worst[n_a].searched):
            assert p_worst[n_a].p_l <= p_mean[n_a].p_l
            assert p_worst[n_a].e_l == pytest.approx(p_mean[n_a].e_l)


def test_readings_are_checked():
    with pytest.raises(SwarmInputError, match="start"):
        SelectionConfig(mc_start="guess")
    with pytest.raises(SwarmInputError, match="worst"):
        SelectionConfig(mc_emax="worst", method="crlb")


def test_recordings_without_the_readings_replay_with_the_estimate_start():
    old = RecordedRun(Path("old.mcap"), {}, {"selection": {"w_v": 0.5, "w_l": 0.5, "samples": 16}})
    assert (recorded_selection(old).mc_start, recorded_selection(old).mc_emax) == ("estimate", "mean")
    new = RecordedRun(Path("new.mcap"), {}, {"selection": {"mc_start": "known", "mc_emax": "worst"}})
    assert (recorded_selection(new).mc_start, recorded_selection(new).mc_emax) == ("known", "worst")
    assert recorded_selection(new, {"mc_start": "estimate"}).mc_start == "estimate"
