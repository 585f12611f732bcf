"""Near-coincident robots as a localization case, shared by the unit tests of degenerate geometry and the
``swarm localize`` command's system tests."""

from __future__ import annotations

import numpy as np

from runtime.models.config import ModelConfig
from runtime.models.geometry import wrap_angle
from runtime.models.scenarios import grid_configuration
from runtime.models.sensing import measure
from runtime.models.state import Observations, SwarmEstimate

CFG = ModelConfig()


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
