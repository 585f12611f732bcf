"""Motion and sensing models: known answers, statistics, seeding."""

from __future__ import annotations

import math

import numpy as np
import pytest

from runtime.errors import SwarmInputError
from runtime.models.config import ModelConfig
from runtime.models.geometry import WRAP_IN_PLACE, wrap_angle
from runtime.models.motion import apply_motion, command_towards, draw_motion_noise, execute_command, motion_covariance
from runtime.models.rng import Stream, robot_rng, robot_rngs
from runtime.models.sensing import add_sensing_noise, measure, sense_robot, sense_swarm


def test_turn_then_drive_known_answer():
    out = apply_motion(np.array([1.0, 2.0, 0.0]), np.array([math.pi / 2, 0.5]))
    np.testing.assert_allclose(out, [1.0, 2.5, math.pi / 2], atol=1e-12)


def test_command_towards_reaches_target_and_wraps():
    pose = np.array([[0.0, 0.0, 3.0], [1.0, 1.0, -3.0]])
    target = np.array([[-1.0, -0.01], [2.0, 1.0]])
    cmd = command_towards(pose, target)
    assert np.all(np.abs(cmd[:, 0]) <= math.pi)
    np.testing.assert_allclose(apply_motion(pose, cmd)[:, :2], target, atol=1e-12)


def test_zero_distance_command_does_not_turn():
    cmd = command_towards(np.array([0.3, 0.3, 1.0]), np.array([0.3, 0.3]))
    np.testing.assert_array_equal(cmd, [0.0, 0.0])


def test_motion_noise_statistics(cfg):
    turn, drive = draw_motion_noise(np.random.default_rng(0), (40000,), cfg)
    assert abs(turn.std() / cfg.turn_sigma_rad - 1) < 0.03
    assert abs(drive.std() / cfg.drive_sigma_frac - 1) < 0.03
    assert abs(turn.mean()) < 3 * cfg.turn_sigma_rad / 200


def test_motion_covariance_matches_monte_carlo(cfg):
    rng = np.random.default_rng(1)
    pose, cmd = np.array([0.1, -0.2, 0.7]), np.array([0.4, 0.3])
    prior_cov = np.diag([1e-4, 2e-4, 1e-3])
    k = 200000
    starts = pose + rng.multivariate_normal(np.zeros(3), prior_cov, k)
    turn, drive = draw_motion_noise(rng, (k,), cfg)
    ends = apply_motion(starts, np.broadcast_to(cmd, (k, 2)), turn, drive)
    empirical = np.cov(ends.T)
    predicted = motion_covariance(pose, prior_cov, cmd, cfg)
    np.testing.assert_allclose(np.diag(predicted), np.diag(empirical), rtol=0.05)


def test_anchor_keeps_prior_covariance(cfg):
    prior = np.diag([1e-4, 1e-4, 1e-3])
    np.testing.assert_allclose(motion_covariance(np.zeros(3), prior, np.zeros(2), cfg), prior)


def test_robot_streams_are_reproducible_and_distinct():
    a = robot_rng(5, 3, Stream.MOTION).normal(size=4)
    b = robot_rng(5, 3, Stream.MOTION).normal(size=4)
    c = robot_rng(5, 4, Stream.MOTION).normal(size=4)
    d = robot_rng(5, 3, Stream.SENSING).normal(size=4)
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c) and not np.allclose(a, d)


def test_execute_command_is_a_pure_function_of_state_command_and_rng(cfg):
    pose, cmd = np.array([0.0, 0.0, 0.2]), np.array([0.1, 0.2])
    one = execute_command(pose, cmd, cfg, robot_rng(1, 0, Stream.MOTION))
    two = execute_command(pose, cmd, cfg, robot_rng(1, 0, Stream.MOTION))
    np.testing.assert_array_equal(one, two)


def test_execute_command_known_answer():
    """Turn-then-drive with the robot's two standard normal draws z_t, z_d (turn first, then drive).

    Pose (1, 2, 0.2), command (turn 0.1, drive 0.2) with s_t = 0.05 rad, s_d = 0.1:
    heading h = 0.2 + 0.1 + 0.05 z_t, distance 0.2 (1 + 0.1 z_d),
    pose (1 + d cos h, 2 + d sin h, h), written out here from the same generator's draws.
    """
    cfg = ModelConfig(turn_sigma_rad=0.05, drive_sigma_frac=0.1)
    z_t, z_d = np.random.Generator(np.random.PCG64(np.random.SeedSequence(1, spawn_key=(0, int(Stream.MOTION))))).normal(size=2)
    h = 0.3 + 0.05 * z_t
    d = 0.2 * (1 + 0.1 * z_d)
    got = execute_command(np.array([1.0, 2.0, 0.2]), np.array([0.1, 0.2]), cfg, robot_rng(1, 0, Stream.MOTION))
    np.testing.assert_allclose(got, [1.0 + d * math.cos(h), 2.0 + d * math.sin(h), h], rtol=0, atol=1e-15)
    assert z_t != 0 and z_d != 0 and not np.allclose(got, apply_motion(np.array([1.0, 2.0, 0.2]), np.array([0.1, 0.2])))


def test_measure_known_answer_and_wrap():
    rng, brg = measure(np.array([0.0, 0.0, math.pi - 0.1]), np.array([-1.0, -0.2]))
    assert rng == pytest.approx(math.hypot(1.0, 0.2))
    expected = (math.atan2(-0.2, -1.0) - (math.pi - 0.1) + math.pi) % (2 * math.pi) - math.pi
    assert brg == pytest.approx(expected)
    assert -math.pi <= brg < math.pi


def test_wrap_angle_of_large_arrays_is_the_formula_to_the_last_bit():
    """Large arrays take the remainder only outside [-pi, pi): the result is (a + pi) mod 2 pi - pi bit for bit,
    at the seams (+-pi, multiples of 2 pi), far out of range, for integers and float32, with NaN and infinities."""
    rng = np.random.default_rng(7)
    angles = np.concatenate([rng.normal(0, 1, 500), rng.normal(0, 40, 500), rng.uniform(-1e7, 1e7, 200),
                             [math.pi, -math.pi, np.nextafter(math.pi, 0), np.nextafter(-math.pi, -4), 2 * math.pi, -2 * math.pi,
                              0.0, -0.0, np.nan, np.inf, -np.inf]])
    assert angles.size >= WRAP_IN_PLACE
    with np.errstate(invalid="ignore"):
        for a in (angles, angles.reshape(11, -1) if angles.size % 11 == 0 else angles[:1100].reshape(11, 100),
                  angles.astype(np.float32), np.arange(-600, 600)):
            got, want = wrap_angle(a), (np.asarray(a) + np.pi) % (2.0 * np.pi) - np.pi
            assert got.dtype == want.dtype and got.shape == want.shape
            np.testing.assert_array_equal(got, want)
    finite = wrap_angle(angles[np.isfinite(angles)])
    assert np.all(np.abs(finite) <= math.pi)  # [-pi, pi) up to the rounding of a + pi
    kept = angles.copy()
    with np.errstate(invalid="ignore"):  # inf
        wrap_angle(kept)
    np.testing.assert_array_equal(kept, angles)  # the input is not written


def test_sensing_respects_range_and_dropout():
    poses = np.array([[0, 0, 0], [0.5, 0, 0], [0.51, 0, 0], [0.2, 0.2, 0]], float)
    np.testing.assert_array_equal(sense_robot(poses, 0, ModelConfig(), np.random.default_rng(0))[0], [1, 3])  # 0.51 m: out
    cfg = ModelConfig(dropout_prob=0.3)
    kept = [len(sense_robot(poses, 0, cfg, np.random.default_rng(s))[0]) for s in range(4000)]
    assert abs(np.mean(kept) / 2 - 0.7) < 0.03


def test_sensing_draws_its_noise_in_the_documented_order(cfg):
    """Robot 1 of four sees robots 0 and 3 (2 of 0.4 m away is out of range): its observations are ``measure``
    plus ``add_sensing_noise`` of 2 uniforms, 2 range normals, 2 bearing normals drawn in that order from its stream
    (what recorded runs and the emulator's robots reproduce), with a heading near pi so the bearings wrap."""
    cfg = ModelConfig(dropout_prob=0.25, sensing_range_m=0.35)
    poses = np.array([[0.0, 0.0, 0.2], [0.3, 0.0, math.pi - 1e-9], [0.7, 0.0, 0.0], [0.3, 0.3, -1.0]])
    got = sense_robot(poses, 1, cfg, np.random.default_rng(7))
    draws = np.random.default_rng(7)
    uniform, z_range, z_bearing = draws.random(2), draws.normal(0.0, 1.0, 2), draws.normal(0.0, 1.0, 2)
    rho, phi = measure(poses[1], poses[[0, 3], :2])
    rho, phi, keep = add_sensing_noise(rho, phi, uniform, z_range, z_bearing, cfg)
    np.testing.assert_array_equal(got[0], np.array([0, 3])[keep])
    np.testing.assert_array_equal(got[1], rho[keep])
    np.testing.assert_array_equal(got[2], phi[keep])


def test_sensing_noise_statistics(cfg):
    poses = np.array([[0, 0, 0.3], [0.3, 0.1, 0]], float)
    rho0, phi0 = measure(poses[0], poses[1, :2])
    draws = np.array([sense_robot(poses, 0, cfg, np.random.default_rng(s))[1:] for s in range(5000)])[:, :, 0]
    assert abs(np.std(draws[:, 0]) / cfg.range_sigma_m - 1) < 0.05
    assert abs(np.std(draws[:, 1] - phi0) / cfg.bearing_sigma_rad - 1) < 0.05
    assert abs(np.mean(draws[:, 0]) - rho0) < 1e-3


def test_swarm_sensing_equals_each_robot_sensing_alone(cfg):
    rng = np.random.default_rng(2)
    poses = np.column_stack([rng.uniform(0, 0.8, (8, 2)), rng.uniform(-3, 3, 8)])
    ids = np.arange(10, 18)
    obs = sense_swarm(poses, ids, cfg, robot_rngs(9, ids, Stream.SENSING))
    for k, rid in enumerate(ids):
        nb, rho, phi = sense_robot(poses, k, cfg, robot_rng(9, rid, Stream.SENSING))
        mine = obs.observer == rid
        np.testing.assert_array_equal(obs.observed[mine], ids[nb])
        np.testing.assert_array_equal(obs.range_m[mine], rho)
        np.testing.assert_array_equal(obs.bearing_rad[mine], phi)


@pytest.mark.parametrize("field,value", [("turn_sigma_rad", float("nan")), ("range_sigma_m", -1.0), ("dropout_prob", 1.0), ("sensing_range_m", 0.0)])
def test_config_rejects_bad_values(field, value):
    with pytest.raises(SwarmInputError, match=field):
        ModelConfig(**{field: value})


def test_a_derived_estimate_equals_from_joint_and_checks_what_it_is_given():
    """``SwarmEstimate.derived`` (a localizer's output for the robots of a validated estimate) keeps the
    prior's ids, takes the 3x3 diagonal blocks of the joint covariance, and names the robot whose
    values are not finite."""
    from runtime.models.state import SwarmEstimate

    prior = SwarmEstimate([7, 3, 5], np.zeros((3, 3)), np.broadcast_to(np.eye(3), (3, 3, 3)))
    poses = np.arange(9.0).reshape(3, 3)
    a = np.arange(81.0).reshape(9, 9)
    joint = a @ a.T + np.eye(9)
    got, want = SwarmEstimate.derived(prior, poses, joint), SwarmEstimate.from_joint([7, 3, 5], poses, joint)
    np.testing.assert_array_equal(got.ids, [7, 3, 5])
    np.testing.assert_array_equal(got.cov, want.cov)
    np.testing.assert_array_equal(got.cov[1], joint[3:6, 3:6])
    np.testing.assert_array_equal(got.joint, joint)
    np.testing.assert_array_equal(got.poses, poses)
    bad = joint.copy()
    bad[4, 0] = np.nan  # a row of robot 3 (the second robot)
    with pytest.raises(SwarmInputError, match=r"robots \[3\]"):
        SwarmEstimate.derived(prior, poses, bad)
    with pytest.raises(SwarmInputError, match="needs poses"):
        SwarmEstimate.derived(prior, poses[:2], joint)
