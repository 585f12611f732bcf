"""The localization around the movers (``coordinator.localization.movers``) does not drift from the whole swarm's
solve over many steps: both localize the same steps of a rough swarm (few movers a step, headings near +-pi,
correlated priors), each from its own estimate, and the errors against the truth are compared chunk by chunk."""

from dataclasses import replace

import numpy as np
import pytest

from coordinator.localization.paper import PaperLocalizer
from runtime.models.config import ModelConfig
from runtime.models.geometry import wrap_angle
from runtime.models.motion import apply_motion, command_towards
from runtime.models.rng import Stream, robot_rngs
from runtime.models.sensing import sense_swarm
from runtime.models.state import StepCommands, SwarmEstimate
from runtime.models.trajectory import body_spacing, random_trajectory

N = 70  # robots, each seeing ~10 others within the short sensing range: one mover's region is ~1/6 of the swarm
CHUNKS, STEPS = 10, 10  # "configurations" of steps, one mover a step, localized around it
WANDER = 0.04  # m: a mover drives to a point this far at most from its start, so the swarm keeps its shape


def drift_run(seed: int, motion_scale: float) -> dict[str, np.ndarray]:
    """Per chunk (CHUNKS,), of the whole swarm's solve and of the localization around the movers: the mean position
    error (m) and the mean position NEES."""
    base = ModelConfig()
    cfg = replace(base, sensing_range_m=0.3, turn_sigma_rad=motion_scale * base.turn_sigma_rad,
                  drive_sigma_frac=motion_scale * base.drive_sigma_frac)
    rng = np.random.default_rng(seed)
    traj = random_trajectory(N, 1, rng, sensing_range=cfg.sensing_range_m, **body_spacing(cfg))
    home = traj.initial_poses[:, :2]
    truth = traj.initial_poses.copy()
    truth[:, 2] = wrap_angle(rng.choice([-np.pi, np.pi - 1e-9], N) + rng.normal(0.0, 0.05, N))
    root = rng.normal(0.0, 1.0, (N, 3, 3)) * np.array([0.004, 0.004, 0.02])[:, None]  # rows scaled: x, y (m), heading
    cov = root @ np.swapaxes(root, 1, 2) + np.diag([1e-6, 1e-6, 1e-5])  # correlated, different per robot
    start = SwarmEstimate(traj.ids, truth + np.einsum("nij,nj->ni", np.linalg.cholesky(cov), rng.normal(0.0, 1.0, (N, 3))), cov)
    localizers = {"whole": PaperLocalizer(cfg, local_min=10**9), "local": PaperLocalizer(cfg, local_min=16)}
    estimate = dict.fromkeys(localizers, start)
    sensing = robot_rngs(seed, traj.ids, Stream.SENSING)
    out = {f"{k}_{m}": np.empty(CHUNKS) for k in localizers for m in ("error", "nees")}
    for chunk in range(CHUNKS):
        for _ in range(STEPS):
            moving = np.zeros(N, bool)
            moving[rng.integers(N)] = True
            target = home + rng.uniform(-WANDER, WANDER, (N, 2)) / np.sqrt(2.0)
            commands = np.where(moving[:, None], command_towards(estimate["whole"].poses, target), 0.0)
            noise = np.where(moving, 1.0, 0.0) * rng.normal(0.0, 1.0, (2, N))
            truth = apply_motion(truth, commands, cfg.turn_sigma_rad * noise[0], cfg.drive_sigma_frac * noise[1])
            observations = sense_swarm(truth, traj.ids, cfg, sensing)
            step = StepCommands(traj.ids, commands, moving)
            for name, localizer in localizers.items():
                estimate[name] = localizer.localize(estimate[name], step, observations)
        for name, est in estimate.items():
            e = est.positions - truth[:, :2]
            out[f"{name}_error"][chunk] = np.hypot(*e.T).mean()
            out[f"{name}_nees"][chunk] = np.einsum("ni,nij,nj->n", e, np.linalg.inv(est.cov[:, :2, :2]), e).mean()
    return out


@pytest.mark.parametrize("motion_scale", [1.0, 3.0])
def test_the_localization_around_the_movers_does_not_drift_from_the_whole_solve(motion_scale: float) -> None:
    run = drift_run(2, motion_scale)
    error = run["local_error"] / run["whole_error"]
    nees = run["local_nees"] / run["whole_nees"]
    assert not np.array_equal(run["local_error"], run["whole_error"])  # localized around the movers, not whole
    for chunks in (slice(0, 3), slice(-3, None)):  # the first "configurations" and the last
        assert error[chunks].mean() < 1.25, error  # not superimposed, the swarm's pose drifted: 1.5-1.9 at the end
        assert nees[chunks].mean() < 1.5, nees  # and not in the covariance: 1.9-2.5
    assert run["local_error"][-3:].mean() < 1.5 * run["local_error"][:3].mean()
