"""Near-coincident robots and degenerate geometry: both localizers stay finite, PSD and JSON-valid."""

from __future__ import annotations

import json

import numpy as np
import pytest

from coordinator.localization import make_localizer
from coordinator.localization.partial import solvable_subset
from coordinator.localization.range_bearing import GATE_SIGMAS, bearing_weights
from coordinator.localization.registry import BUILTIN_LOCALIZERS
from inchworm.localize_data import localize_document
from runtime.errors import LocalizationError
from runtime.models.config import ModelConfig
from runtime.models.geometry import wrap_angle
from runtime.models.scenarios import grid_configuration
from runtime.models.sensing import measure
from runtime.models.state import Observations, StepCommands, SwarmEstimate

CFG = ModelConfig()
REASONS = {"unobserved", "disconnected", "no-convergence", "degenerate"}


def close_pair_case(n: int, gap: float, exact: bool, seed: int):
    """n robots on a jittered grid, the last one ``gap`` m from robot 0; noisy observations within range.

    With ``exact`` False the pair's bearings are uniformly random (meaningless at that range).
    Returns (truth (n, 3), observations, prior with the declared error).
    """
    rng = np.random.default_rng([seed, n])
    truth = grid_configuration(n - 1, 0.25, rng)
    angle = rng.uniform(-np.pi, np.pi)
    extra = np.array([truth[0, 0] + gap * np.cos(angle), truth[0, 1] + gap * np.sin(angle), rng.uniform(-np.pi, np.pi)])
    truth = np.vstack([truth, extra])
    rho, phi = measure(truth[:, None, :], truth[None, :, :2])
    rho = np.maximum(rho + rng.normal(size=rho.shape) * CFG.range_sigma_m, 0.0)
    phi = wrap_angle(phi + rng.normal(size=phi.shape) * CFG.bearing_sigma_rad)
    if not exact:
        phi[0, n - 1], phi[n - 1, 0] = rng.uniform(-np.pi, np.pi, 2)
    i, j = np.nonzero((rho <= CFG.sensing_range_m) & ~np.eye(n, dtype=bool))
    obs = Observations(i, j, rho[i, j], phi[i, j])
    prior = SwarmEstimate.isotropic(np.arange(n), truth + rng.normal(size=truth.shape) * [0.014, 0.014, 0.035], 0.02, 0.035)
    return truth, obs, prior


def document(obs: Observations, prior: SwarmEstimate | None, n: int) -> dict:
    doc = {"robots": list(range(n)),
           "observations": [[int(a), int(b), float(r), float(p)] for a, b, r, p in zip(obs.observer, obs.observed, obs.range_m, obs.bearing_rad,
                                                                                       strict=True)]}
    if prior is not None:
        doc["prior"] = [{"id": k, "x": p[0], "y": p[1], "heading": p[2], "delta": 0.02, "sigma_heading": 0.035}
                        for k, p in enumerate(prior.poses.tolist())]
    return doc


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
