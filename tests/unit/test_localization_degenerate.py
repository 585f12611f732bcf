"""Near-coincident robots and degenerate geometry: both localizers stay finite, PSD and JSON-valid."""

from __future__ import annotations

import json

import numpy as np
import pytest
from localize_cases import CFG, close_pair_case, document

from coordinator.localization import make_localizer
from coordinator.localization.partial import solvable_subset
from coordinator.localization.range_bearing import GATE_SIGMAS, bearing_weights
from coordinator.localization.registry import BUILTIN_LOCALIZERS
from inchworm.localize_data import localize_document
from runtime.errors import LocalizationError
from runtime.models.state import Observations, StepCommands

REASONS = {"unobserved", "disconnected", "no-convergence", "degenerate"}


@pytest.mark.parametrize("localizer", BUILTIN_LOCALIZERS)
@pytest.mark.parametrize("gap", [0.0, 0.005, 0.1])
@pytest.mark.parametrize("exact", [True, False])
@pytest.mark.parametrize("with_prior", [True, False])
def test_close_pair_gives_valid_answers(localizer, gap, exact, with_prior):
    for seed, n in enumerate(range(6, 11)):
        truth, obs, prior = close_pair_case(n, gap, exact, seed)
        for robust in (True, False):
            out = localize_document(document(obs, prior if with_prior else None, n), CFG, localizer, strict=False, robust=robust).to_json()
            json.dumps(out, allow_nan=False)  # no NaN/Infinity anywhere
            left_out = {e["id"] for e in out["excluded"]}
            assert {e["reason"] for e in out["excluded"]} <= REASONS
            assert {r["id"] for r in out["robots"]} | left_out == set(range(n))
            assert len(left_out) <= 2, out["excluded"]  # at most the pair's worth of robots set aside
            if with_prior:
                for r in out["robots"]:
                    assert r["delta_p"] > 0.0  # never a clamped zero variance
                    assert np.hypot(r["x"] - truth[r["id"], 0], r["y"] - truth[r["id"], 1]) < 0.08


@pytest.mark.parametrize("localizer", BUILTIN_LOCALIZERS)
@pytest.mark.parametrize("gap", [0.0, 0.005, 0.1])
def test_close_pair_covariances_are_positive_semidefinite(localizer, gap):
    loc = make_localizer(localizer, CFG)
    for seed, n in enumerate(range(6, 11)):
        _, obs, prior = close_pair_case(n, gap, False, seed)
        try:
            est = loc.localize(prior, StepCommands.stationary(prior.ids), obs)
        except LocalizationError as exc:
            assert exc.reason in REASONS and 0 < len(exc.robots) < n
            continue
        assert np.all(np.linalg.eigvalsh(est.cov) >= -1e-15)
        if est.joint is not None:
            assert np.linalg.eigvalsh(est.joint).min() >= -1e-12 * np.abs(est.joint).max()


def test_bearing_weight_fades_below_a_few_range_sigmas():
    s_b = CFG.bearing_sigma_rad
    gate = GATE_SIGMAS * CFG.range_sigma_m
    w = bearing_weights(np.array([0.0, 0.005, gate, 0.1, 0.25, 0.5]), CFG)
    assert w[0] == 0.0 and np.all(np.diff(w) > 0)
    assert w[2] == pytest.approx(1.0 / (s_b * np.sqrt(2.0)))  # s_b(rho) = s_b sqrt(2) at the gate
    assert w[4] == pytest.approx(1.0 / s_b, rel=1e-3)  # unchanged at a typical range
    assert w[1] < 0.03 / s_b  # a 5 mm bearing is nearly meaningless


def test_solver_failure_sets_the_named_robots_aside_and_solves_the_rest():
    ids = np.array([3, 5, 7, 9])
    pairs = np.array([[3, 5], [5, 3], [5, 7], [7, 5], [7, 3], [3, 7], [9, 3], [3, 9]])
    obs = Observations(pairs[:, 0], pairs[:, 1], np.full(len(pairs), 0.2), np.zeros(len(pairs)))
    calls = []

    def solve(keep):
        calls.append(ids[keep].tolist())
        if 9 in ids[keep]:
            raise LocalizationError("no-convergence", [9], "test")
        return ids[keep]

    keep, result, excluded = solvable_subset(solve, ids, obs)
    assert excluded == {9: "no-convergence"} and result.tolist() == [3, 5, 7]
    assert calls == [[3, 5, 7, 9], [3, 5, 7]]
    with pytest.raises(LocalizationError, match="no-convergence"):
        solvable_subset(solve, ids, obs, retry=False)

    def always(keep):
        raise LocalizationError("no-convergence", ids[keep], "everyone")

    with pytest.raises(LocalizationError):  # naming everyone leaves nothing to solve
        solvable_subset(always, ids, obs)
