"""Joint covariance bookkeeping (SwarmEstimate.joint) and the NEES consistency study."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from coordinator.consistency import chi2_band, position_nees
from coordinator.localization import make_localizer
from coordinator.localization.dead_reckoning import dead_reckon
from runtime.config import ModelConfig
from runtime.errors import SwarmInputError
from runtime.scenarios import random_step
from runtime.state import SwarmEstimate

ROOT = Path(__file__).resolve().parents[1]
CFG = ModelConfig()


def random_joint(n: int, seed: int) -> np.ndarray:
    a = np.random.default_rng(seed).normal(size=(3 * n, 3 * n)) * 0.01
    return a @ a.T + 1e-4 * np.eye(3 * n)


def test_select_marginalises_the_joint_covariance():
    joint = random_joint(4, 0)
    est = SwarmEstimate.from_joint([10, 11, 12, 13], np.zeros((4, 3)), joint)
    np.testing.assert_array_equal(est.cov[2], joint[6:9, 6:9])
    sub = est.select(np.array([True, False, True, False]))
    np.testing.assert_array_equal(sub.joint, joint[np.r_[0:3, 6:9]][:, np.r_[0:3, 6:9]])
    np.testing.assert_array_equal(sub.cov, est.cov[[0, 2]])
    assert est.select(np.array([False, True, True, True])).select(np.array([True, False, True])).joint.shape == (6, 6)
    plain = SwarmEstimate.isotropic([1, 2], np.zeros((2, 3)), 0.01, 0.01)
    assert plain.joint is None and plain.select(np.array([True, False])).joint is None
    with pytest.raises(SwarmInputError, match="joint covariance must have shape"):
        SwarmEstimate([1, 2], np.zeros((2, 3)), plain.cov, np.eye(3))


def test_dead_reckoning_propagates_the_joint_covariance_consistently_with_the_marginals():
    case = random_step(6, CFG, np.random.default_rng(1))
    joint = random_joint(6, 1)
    prior = SwarmEstimate.from_joint(case.prior.ids, case.prior.poses, joint)
    dr = dead_reckon(prior, case.step, CFG)
    marginal = dead_reckon(SwarmEstimate(prior.ids, prior.poses, prior.cov), case.step, CFG)
    np.testing.assert_allclose(dr.cov, marginal.cov, rtol=1e-12, atol=1e-18)
    np.testing.assert_array_equal(dr.poses, marginal.poses)
    still = ~case.step.moving
    idx = (3 * np.flatnonzero(still))[:, None] + np.arange(3)
    np.testing.assert_allclose(dr.joint[idx.ravel()][:, idx.ravel()], joint[idx.ravel()][:, idx.ravel()])  # anchors untouched


def test_joint_localizer_carries_the_joint_covariance():
    case = random_step(8, CFG, np.random.default_rng(2))
    loc = make_localizer("joint", CFG)
    first = loc.localize(case.prior, case.step, case.observations)
    assert first.joint is not None
    np.testing.assert_allclose(first.cov, SwarmEstimate.from_joint(first.ids, first.poses, first.joint).cov)
    # A joint prior that is block-diagonal is the same information as the per-robot marginals.
    blocky = SwarmEstimate.from_joint(case.prior.ids, case.prior.poses, _block(case.prior.cov))
    again = loc.localize(blocky, case.step, case.observations)
    np.testing.assert_allclose(again.poses, first.poses, atol=1e-9)
    np.testing.assert_allclose(again.joint, first.joint, rtol=1e-6, atol=1e-15)
    # Correlations change the answer: the second step's prior holds them.
    step2 = loc.localize(first, case.step, case.observations)
    assert step2.joint is not None and np.all(step2.delta <= first.delta + 1e-12)


def _block(cov: np.ndarray) -> np.ndarray:
    n = len(cov)
    out = np.zeros((3 * n, 3 * n))
    for k in range(n):
        out[3 * k : 3 * k + 3, 3 * k : 3 * k + 3] = cov[k]
    return out


def test_position_nees_known_answer():
    cov = np.zeros((2, 3, 3))
    cov[:, 0, 0], cov[:, 1, 1], cov[:, 2, 2] = 0.01, 0.04, 1.0
    truth = np.array([[0.1, 0.0, 0.0], [0.0, 0.2, 0.0]])
    assert position_nees(truth, np.zeros((2, 3)), cov) == pytest.approx(((1.0 + 1.0) / 2) / 2)
    zero = np.zeros((2, 3, 3))
    assert position_nees(truth, np.zeros((2, 3)), zero) == np.inf
    low, high = chi2_band(10, 4)
    assert low < 1.0 < high and high - low < 0.7


def test_study_consistency_json_contract(tmp_path):
    out = subprocess.run(
        [sys.executable, "-m", "swarm_cli.main", "study", "consistency", "--configs", "2", "--trajectories", "1",
         "--robots", "6", "--methods", "no-anchors,ref57", "--out", str(tmp_path), "--json"],
        capture_output=True, text=True, timeout=600, cwd=ROOT,
    )
    assert out.returncode == 0, out.stderr
    doc = json.loads(out.stdout.strip().splitlines()[-1])
    assert list(doc) == ["rows"]
    assert [(r["localizer"], r["method"]) for r in doc["rows"]] == [
        ("paper", "no-anchors"), ("paper", "ref57"), ("joint", "no-anchors"), ("joint", "ref57")]
    for r in doc["rows"]:
        assert list(r) == ["localizer", "method", "configs", "nees_over_expected_median", "nees_over_expected_max"]
        assert r["configs"] == 2 and 0 < r["nees_over_expected_median"] <= r["nees_over_expected_max"]
    assert (tmp_path / "consistency.png").stat().st_size > 0
    bad = subprocess.run([sys.executable, "-m", "swarm_cli.main", "study", "consistency", "--methods", "nope"],
                         capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert bad.returncode == 2 and "--methods" in bad.stderr and "Traceback" not in bad.stderr
