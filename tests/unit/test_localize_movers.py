"""A large swarm's step localized around its movers (``coordinator.localization.movers``) against the whole swarm's
solve, on a rough mid-size swarm (the size threshold lowered through ``PaperLocalizer(local_min=...)``)."""

import numpy as np
import pytest

from coordinator.localization import movers
from coordinator.localization.paper import PaperLocalizer
from runtime.models.config import ModelConfig
from runtime.models.geometry import wrap_angle
from runtime.models.motion import apply_motion
from runtime.models.rng import Stream, robot_rngs
from runtime.models.sensing import sense_swarm
from runtime.models.state import Observations, StepCommands, SwarmEstimate
from runtime.models.trajectory import body_spacing, random_trajectory

CFG = ModelConfig()
N = 400
WHOLE = PaperLocalizer(CFG, local_min=10**9)  # never around the movers: the whole swarm's solve
LOCAL = PaperLocalizer(CFG, local_min=100)


def rough_step(seed: int, n_moving: int) -> tuple[SwarmEstimate, StepCommands, Observations, np.ndarray]:
    """(prior, step, observations, true poses after it) of ``N`` robots with headings near +-pi, priors drawn from
    correlated 3x3 covariances, ``n_moving`` robots turning and driving with the model's motion noise."""
    rng = np.random.default_rng(seed)
    traj = random_trajectory(N, 1, rng, sensing_range=CFG.sensing_range_m, **body_spacing(CFG))
    truth = traj.initial_poses.copy()
    truth[:, 2] = wrap_angle(rng.choice([-np.pi, np.pi - 1e-9], N) + rng.normal(0.0, 0.02, N))
    root = rng.normal(0.0, 1.0, (N, 3, 3)) * np.array([0.004, 0.004, 0.01])[:, None]  # rows scaled: x, y (m), heading
    cov = root @ np.swapaxes(root, 1, 2)  # correlated, different per robot
    prior = SwarmEstimate(traj.ids, truth + np.einsum("nij,nj->ni", np.linalg.cholesky(cov), rng.normal(0.0, 1.0, (N, 3))), cov)
    moving = np.zeros(N, bool)
    moving[rng.choice(N, n_moving, replace=False)] = True
    commands = np.where(moving[:, None], np.column_stack([rng.uniform(-0.5, 0.5, N), rng.uniform(0.02, 0.06, N)]), 0.0)
    after = apply_motion(truth, commands, rng.normal(0.0, CFG.turn_sigma_rad, N), rng.normal(0.0, CFG.drive_sigma_frac, N))
    obs = sense_swarm(after, traj.ids, CFG, robot_rngs(seed, traj.ids, Stream.SENSING))
    return prior, StepCommands(traj.ids, commands, moving), obs, after


@pytest.mark.parametrize("seed", [3, 8])
def test_the_movers_region_agrees_with_the_whole_swarm_within_a_fraction_of_sigma(seed: int) -> None:
    prior, step, obs, truth = rough_step(seed, 3)
    i, j = obs.indexed(prior.ids)
    region = movers.hops_from(step.moving, i, j, movers.RING_HOPS) >= 0
    assert 3 < region.sum() <= movers.LOCAL_MAX_FRACTION * N  # a ring around the movers, not the swarm
    whole, local = WHOLE.localize(prior, step, obs), LOCAL.localize(prior, step, obs)
    assert not np.array_equal(whole.poses, local.poses)  # the region was solved, not the whole swarm
    assert N < movers.LOCAL_MIN  # the default threshold: the whole swarm, bit for bit
    np.testing.assert_array_equal(PaperLocalizer(CFG).localize(prior, step, obs).poses, whole.poses)
    sigma, sigma_heading = whole.delta, whole.sigma_heading
    off = np.hypot(*(local.positions - whole.positions).T) / sigma
    turned = np.abs(wrap_angle(local.poses[:, 2] - whole.poses[:, 2])) / sigma_heading
    m = step.moving
    assert off[m].max() < 0.25 and turned[m].max() < 0.15  # the movers: a small fraction of their own sigma
    assert np.median(off) < 0.15 and np.percentile(off, 99) < 0.7  # everyone: placed by its neighbours' priors
    assert np.median(turned) < 0.25
    assert np.all(np.abs(local.poses[:, 2]) <= np.pi)
    ratio = local.delta / whole.delta  # clusters placed by priors spread by the priors' errors: a little wider
    assert 1.0 <= np.median(ratio) < 1.15 and ratio.min() > 0.9 and ratio.max() < 1.7
    np.testing.assert_allclose(local.sigma_heading, whole.sigma_heading, rtol=1e-9)
    error = [np.hypot(*(est.positions - truth[:, :2]).T) for est in (local, whole)]
    assert error[0][m].mean() < 1.2 * error[1][m].mean() + 1e-3  # as close to the truth (m)
    assert np.mean(error[0]) < 1.1 * np.mean(error[1])


@pytest.mark.parametrize("n_moving", [0, 150])
def test_no_movers_or_a_large_region_solve_the_whole_swarm(n_moving: int) -> None:
    prior, step, obs, _ = rough_step(5, n_moving)
    whole, local = WHOLE.localize(prior, step, obs), LOCAL.localize(prior, step, obs)
    np.testing.assert_array_equal(local.poses, whole.poses)  # bit for bit: the same path
    np.testing.assert_array_equal(local.cov, whole.cov)


def test_hops_follow_observations_both_ways() -> None:
    observer, observed = np.array([0, 2, 2, 4]), np.array([1, 1, 3, 3])  # a chain 0 - 1 - 2 - 3 - 4, mixed directions
    seed = np.array([False, True, False, False, False])
    assert movers.hops_from(seed, observer, observed, 2).tolist() == [1, 0, 1, 2, -1]
