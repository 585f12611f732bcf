"""Localizers (paper and joint): exactness, invariance, anchors, failure modes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from coordinator.localization import make_localizer
from coordinator.localization.dead_reckoning import dead_reckon, exact_moments
from coordinator.localization.graph import observable_subset
from coordinator.localization.registry import BUILTIN_LOCALIZERS
from runtime.errors import LocalizationError, SwarmInputError
from runtime.models.config import ModelConfig
from runtime.models.geometry import rotate, transform_poses, wrap_angle
from runtime.models.rng import Stream, robot_rngs
from runtime.models.scenarios import grid_configuration, random_step
from runtime.models.sensing import sense_swarm
from runtime.models.state import Observations, StepCommands, SwarmEstimate

METHODS = BUILTIN_LOCALIZERS


def in_frame_of(poses: np.ndarray, ref: int) -> np.ndarray:
    """Poses expressed in robot ``ref``'s body frame."""
    out = poses.copy()
    out[:, :2] = rotate(-poses[ref, 2], poses[:, :2] - poses[ref, :2])
    out[:, 2] = wrap_angle(poses[:, 2] - poses[ref, 2])
    return out


def swarm(n: int, seed: int) -> np.ndarray:
    poses = grid_configuration(n, 0.22, np.random.default_rng(seed))
    poses[0, 2] = math.pi - 1e-4  # headings and bearings across the +-pi seam
    poses[1, 2] = -math.pi + 1e-4
    return poses


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_noise_free_topology_is_exact(method, seed, exact_sensing):
    poses = swarm(12, seed)
    ids = np.arange(100, 112)
    obs = sense_swarm(poses, ids, exact_sensing, robot_rngs(seed, ids, Stream.SENSING))
    topo = make_localizer(method, exact_sensing).topology(ids, obs)
    truth = in_frame_of(poses, topo.reference)
    np.testing.assert_allclose(topo.positions, truth[:, :2], atol=1e-9)
    np.testing.assert_allclose(wrap_angle(topo.headings - truth[:, 2]), 0.0, atol=1e-9)


@pytest.mark.parametrize("method", METHODS)
def test_noise_free_step_recovers_true_configuration(method, exact_sensing):
    rng = np.random.default_rng(3)
    poses = swarm(10, 3)
    ids = np.arange(10)
    prior = SwarmEstimate.isotropic(ids, poses, 0.01, 0.02)
    moving = np.arange(10) % 2 == 0
    commands = np.column_stack([rng.uniform(-1, 1, 10), rng.uniform(0.05, 0.15, 10)])
    step = StepCommands(ids, commands, moving)
    loc = make_localizer(method, exact_sensing)
    after = dead_reckon(prior, step, exact_sensing, exact_moments(loc)).poses  # the motion the localizer expects
    obs = sense_swarm(after, ids, exact_sensing, robot_rngs(0, ids, Stream.SENSING))
    est = loc.localize(prior, step, obs)
    np.testing.assert_allclose(est.positions, after[:, :2], atol=1e-9)
    np.testing.assert_allclose(wrap_angle(est.poses[:, 2] - after[:, 2]), 0.0, atol=1e-9)


@pytest.mark.parametrize("method", METHODS)
def test_rigid_motion_of_the_scene_moves_the_estimate_alike(method, cfg):
    case = random_step(15, cfg, np.random.default_rng(4), spacing=0.22)
    loc = make_localizer(method, cfg)
    est = loc.localize(case.prior, case.step, case.observations)
    theta, t = 2.1, np.array([3.0, -1.5])
    moved_prior = SwarmEstimate(case.prior.ids, transform_poses(case.prior.poses, theta, t), rotate_cov(case.prior.cov, theta))
    moved = loc.localize(moved_prior, case.step, case.observations)
    np.testing.assert_allclose(moved.poses[:, :2], transform_poses(est.poses, theta, t)[:, :2], atol=1e-9)
    np.testing.assert_allclose(wrap_angle(moved.poses[:, 2] - est.poses[:, 2] - theta), 0.0, atol=1e-9)
    np.testing.assert_allclose(moved.delta, est.delta, rtol=1e-6)


def rotate_cov(cov: np.ndarray, theta: float) -> np.ndarray:
    r = np.eye(3)
    r[:2, :2] = [[math.cos(theta), -math.sin(theta)], [math.sin(theta), math.cos(theta)]]
    return r @ cov @ r.T


@pytest.mark.parametrize("method", METHODS)
def test_precise_anchors_make_fusion_beat_dead_reckoning(method, cfg):
    fused, dr = [], []
    for seed in range(20):
        rng = np.random.default_rng(100 + seed)
        case = random_step(10, cfg, rng, spacing=0.2, prior_delta=1e-4, prior_heading_sigma=1e-3, move=0.3, seed=seed)
        est = make_localizer(method, cfg).localize(case.prior, case.step, case.observations)
        truth = case.true_after[:, :2]
        fused.append(np.mean(np.linalg.norm(est.positions - truth, axis=1)))
        dr.append(np.mean(np.linalg.norm(dead_reckon(case.prior, case.step, cfg).positions - truth, axis=1)))
    assert np.mean(fused) < 0.8 * np.mean(dr)


def test_joint_is_more_accurate_than_paper_on_average(cfg):
    errs = {m: [] for m in METHODS}
    for seed in range(10):
        case = random_step(20, cfg, np.random.default_rng(seed), spacing=0.22)
        for m in METHODS:
            est = make_localizer(m, cfg).localize(case.prior, case.step, case.observations)
            errs[m].append(np.mean(np.linalg.norm(est.positions - case.true_after[:, :2], axis=1)))
    assert np.mean(errs["joint"]) < np.mean(errs["paper"])


@pytest.mark.parametrize("method", METHODS)
def test_topology_does_not_depend_on_the_initial_guess(method, cfg):
    case = random_step(12, cfg, np.random.default_rng(5), spacing=0.22)
    loc = make_localizer(method, cfg)
    cold = loc.topology(case.prior.ids, case.observations)
    warm = loc.topology(case.prior.ids, case.observations, initial_poses=case.true_after)
    np.testing.assert_allclose(cold.positions, warm.positions, atol=1e-7)


def test_robot_observing_nobody_keeps_dead_reckoning_heading(cfg):
    case = random_step(8, cfg, np.random.default_rng(6), spacing=0.2)
    obs = case.observations
    keep = obs.observer != 3
    one_way = obs.select(keep)
    loc = make_localizer("paper", cfg)
    assert np.isnan(loc.topology(case.prior.ids, one_way).headings[3])
    est = loc.localize(case.prior, case.step, one_way)
    assert est.poses[3, 2] == pytest.approx(dead_reckon(case.prior, case.step, cfg).poses[3, 2])


@pytest.mark.parametrize("method", METHODS)
def test_unobserved_robot_is_named(method, cfg):
    """Robot 5 with no observation either way is named; seen by nobody but seeing others, it is localized
    from what it saw (its uncertainty shrinks below dead reckoning's, and the truth lies within 3 of it)."""
    case = random_step(8, cfg, np.random.default_rng(7), spacing=0.2)
    obs = case.observations
    silent = obs.select((obs.observed != 5) & (obs.observer != 5))
    with pytest.raises(LocalizationError, match=r"unobserved: robots \[5\]") as info:
        make_localizer(method, cfg).localize(case.prior, case.step, silent)
    assert info.value.robots == [5]
    blind = obs.select(obs.observed != 5)
    assert (blind.observer == 5).sum() >= 2
    est = make_localizer(method, cfg).localize(case.prior, case.step, blind)
    dr = dead_reckon(case.prior, case.step, cfg)
    assert est.delta[5] < 0.8 * dr.delta[5]
    assert np.hypot(*(est.poses[5, :2] - case.true_after[5, :2])) < 3 * est.delta[5]


@pytest.mark.parametrize("method", METHODS)
def test_disconnected_groups_are_named(method, cfg):
    ids = np.arange(6)
    poses = np.array([[0, 0, 0], [0.2, 0, 0], [0.1, 0.2, 0], [3, 3, 0], [3.2, 3, 0], [3.1, 3.2, 0]], float)
    poses[:, 2] = [0.1, 1.0, 2.0, -1.0, 0.3, 2.5]
    obs = sense_swarm(poses, ids, cfg, robot_rngs(0, ids, Stream.SENSING))
    prior = SwarmEstimate.isotropic(ids, poses, 0.01, 0.01)
    with pytest.raises(LocalizationError, match="disconnected") as info:
        make_localizer(method, cfg).localize(prior, StepCommands.stationary(ids), obs)
    assert info.value.robots == [3, 4, 5]


def test_observable_subset_drops_and_explains():
    ids = np.array([1, 2, 3, 4, 5])
    # 1<->2<->3 connected, 4 sees 5 but nobody sees 4, so 5 alone is cut off.
    observer = np.array([0, 1, 1, 2, 3])
    observed = np.array([1, 0, 2, 1, 4])
    keep, why = observable_subset(ids, observer, observed)
    np.testing.assert_array_equal(keep, [True, True, True, False, False])
    assert why == {4: "unobserved", 5: "disconnected"}


@pytest.mark.parametrize("method", METHODS)
def test_unknown_ids_and_nan_are_rejected(method, cfg):
    case = random_step(6, cfg, np.random.default_rng(8), spacing=0.2)
    obs = case.observations
    with pytest.raises(SwarmInputError, match=r"unknown robot ids in observations: \[42\]"):
        bad = Observations(np.append(obs.observer, 42), np.append(obs.observed, 0), np.append(obs.range_m, 0.1), np.append(obs.bearing_rad, 0.0))
        make_localizer(method, cfg).localize(case.prior, case.step, bad)
    with pytest.raises(SwarmInputError, match=r"NaN/inf .*\(2, "):
        rng = obs.range_m.copy()
        rng[np.flatnonzero(obs.observer == 2)[0]] = np.nan
        Observations(obs.observer, obs.observed, rng, obs.bearing_rad)
    with pytest.raises(SwarmInputError, match=r"poses hold NaN/inf for robots \[4\]"):
        poses = case.prior.poses.copy()
        poses[4, 1] = np.inf
        SwarmEstimate(case.prior.ids, poses, case.prior.cov)
    with pytest.raises(SwarmInputError, match="step commands are for robots"):
        make_localizer(method, cfg).localize(case.prior, StepCommands.stationary(np.arange(1, 7)), obs)


def test_fused_uncertainty_is_smaller_for_anchors_than_movers(cfg):
    case = random_step(12, cfg, np.random.default_rng(9), spacing=0.2, prior_delta=0.005, move=0.3)
    for method in METHODS:
        est = make_localizer(method, cfg).localize(case.prior, case.step, case.observations)
        assert est.delta[~case.step.moving].mean() < est.delta[case.step.moving].mean()


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("offset", [(0.0, 0.0), (0.03, -0.02)])
def test_exact_data_known_answer(method, offset):
    """No motion or sensing noise, the prior off by a common ``offset`` (m) for every robot.

    Dead reckoning (Eq. 17-19) is then truth + offset for everyone (same heading, same command,
    same displacement); the exact topology superimposed on it (Eq. 21) lands on truth + offset
    too, and so does their midpoint (Eq. 23). The joint solution has the same minimum (the
    observations are relative). Observations cannot see a common shift: estimate = truth + offset.
    """
    exact = ModelConfig(turn_sigma_rad=0.0, drive_sigma_frac=0.0, range_sigma_m=0.0, bearing_sigma_rad=0.0)
    case = random_step(10, exact, np.random.default_rng(12), prior_delta=0.0, prior_heading_sigma=0.0)
    shifted = case.prior.poses + [offset[0], offset[1], 0.0]
    prior = SwarmEstimate(case.prior.ids, shifted, case.prior.cov + np.diag([1e-6, 1e-6, 1e-6]))
    est = make_localizer(method, exact).localize(prior, case.step, case.observations)
    np.testing.assert_allclose(est.positions - case.true_after[:, :2], np.broadcast_to(offset, (10, 2)), atol=1e-7)
    np.testing.assert_allclose(wrap_angle(est.poses[:, 2] - case.true_after[:, 2]), 0.0, atol=1e-7)


@pytest.mark.parametrize("method", METHODS)
def test_localization_is_deterministic(method, cfg):
    case = random_step(10, cfg, np.random.default_rng(10))
    a = make_localizer(method, cfg).localize(case.prior, case.step, case.observations)
    b = make_localizer(method, cfg).localize(case.prior, case.step, case.observations)
    np.testing.assert_array_equal(a.poses, b.poses)
    np.testing.assert_array_equal(a.cov, b.cov)


@pytest.mark.parametrize("method", METHODS)
def test_partial_localization_keeps_dead_reckoning_only_for_the_lost_robot(method, cfg):
    from coordinator.localization.partial import localize_observable

    case = random_step(10, cfg, np.random.default_rng(11), spacing=0.2)
    obs = case.observations
    keep = (obs.observed != 7) & (obs.observer != 7)  # robot 7 is out of everyone's sight
    lost = obs.select(keep)
    loc = make_localizer(method, cfg)
    est, excluded = localize_observable(loc, case.prior, case.step, lost, cfg)
    assert excluded == {7: "unobserved"}
    dr = dead_reckon(case.prior, case.step, cfg, exact_moments(loc))
    np.testing.assert_array_equal(est.poses[7], dr.poses[7])
    others = np.arange(10) != 7
    assert not np.allclose(est.poses[others], dr.poses[others])
    full, none = localize_observable(loc, case.prior, case.step, obs, cfg)
    assert none == {}
    np.testing.assert_array_equal(full.poses, loc.localize(case.prior, case.step, obs).poses)
