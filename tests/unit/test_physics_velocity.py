"""The physical world behind the simulated ROS 2 robots' velocity seam (runtime.world.velocity): cmd_vel as wheel speeds
within their limits, odometry from the wheel encoders (blind to the wheels' factors, slip and pushes), the quiet moments."""

from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("pymunk")

from runtime.errors import SwarmInputError
from runtime.models.config import ModelConfig
from runtime.models.world import make_world
from runtime.world.params import PhysicsParams
from runtime.world.physics import Contact, World
from runtime.world.velocity import PhysicsWorld

P = PhysicsParams()


def drive(world: PhysicsWorld, twists, seconds: float, dt: float = 0.02) -> None:
    for _ in range(round(seconds / dt)):
        world.step(dt, np.asarray(twists, dtype=float))


def test_a_twist_turns_then_drives_within_the_wheel_limits_and_the_encoders_count_the_commanded_motion():
    """Heading near +pi: the turn wraps. The odometry is the commanded motion (as the encoders count it, ramps included);
    the truth differs by the motion's wheel-speed factors, drawn once from rest (the turn and the drive share them)."""
    w = PhysicsWorld(np.array([4]), np.array([[0.1, -0.2, math.pi - 0.01]]), P, seed=5)
    drive(w, [[0.0, 1.0]], 0.5)  # turn counter-clockwise at 1 rad/s: past +pi
    drive(w, [[0.0, 0.0]], 0.1)  # the wheels stop (from one wheel speed to another, each ramps on its own: the robot would curve)
    drive(w, [[0.04, 0.0]], 2.0)  # then straight ahead at 0.04 m/s
    drive(w, [[0.0, 0.0]], 0.5)
    odom, true = w.odometry()[0], w.poses()[0]
    assert abs(math.remainder(odom[2] - (math.pi - 0.01 + 0.5), 2 * math.pi)) < 0.01  # the turn, less its ramps' lag
    travelled = math.hypot(odom[0] - 0.1, odom[1] + 0.2)
    assert travelled == pytest.approx(0.08, abs=0.002) and np.all(w.speeds() == 0.0)
    assert abs(math.remainder(true[2] - odom[2], 2 * math.pi)) > 1e-4 and not np.allclose(true[:2], odom[:2], atol=1e-4)
    assert np.hypot(*(true[:2] - odom[:2])) < 0.1 * travelled  # factors of a few %, not a different motion
    fast = PhysicsWorld(np.array([0]), np.zeros((1, 3)), P, seed=5)
    fast.step(0.1, np.array([[9.0, 0.0]]))  # far beyond the wheels: the motors reach it at their acceleration ...
    assert fast.speeds()[0, 0] == pytest.approx(0.1 * P.max_wheel_accel_m_s2)
    fast.step(1.0, np.array([[9.0, 0.0]]))  # ... capped at their speed (the ground: that times the wheels' factors)
    assert fast.speeds()[0].tolist() == [P.max_wheel_speed_m_s, 0.0]


def test_the_same_seed_gives_the_same_world_and_a_new_motion_new_wheel_factors():
    def run(seed: int) -> np.ndarray:
        w = PhysicsWorld(np.array([0, 1]), np.array([[0.0, 0.0, 0.0], [0.3, 0.0, 3.0]]), P, seed)
        drive(w, [[0.05, 0.0], [0.03, 0.2]], 1.0)
        drive(w, [[0.0, 0.0], [0.0, 0.0]], 0.5)
        drive(w, [[0.05, 0.0], [0.0, 0.0]], 1.0)
        return w.poses()

    assert np.array_equal(run(1), run(1)) and not np.allclose(run(1), run(2))
    w = World([0], np.zeros((1, 3)), P, seed=0, encoders=True)
    w.set_twist(0, 0.04, 0.0)
    w.step(10)
    first = w._robots[0].scale
    w.set_twist(0, 0.0, 1.0)  # still moving: the same motion, the same factors
    assert w._robots[0].scale == first
    w.halt(0)
    w.settle()
    w.set_twist(0, 0.04, 0.0)  # from rest: a new motion
    assert w._robots[0].scale != first
    w.set_wheel_speeds(0, 0.02, 0.02)  # exact wheel control: no factors
    assert w._robots[0].scale == [1.0, 1.0]


def test_a_push_moves_a_standing_robot_its_encoders_do_not_see_and_the_quiet_moment_reports_the_contact():
    w = PhysicsWorld(np.array([0, 1]), np.array([[0.0, 0.0, 0.0], [0.05, 0.0, 0.0]]), P, seed=0)
    assert w.take_quiet() is None  # nothing moved yet
    drive(w, [[0.04, 0.0], [0.0, 0.0]], 1.5)
    assert w.take_quiet() is None  # still moving
    drive(w, [[0.0, 0.0], [0.0, 0.0]], 1.0)
    quiet = w.take_quiet()
    assert quiet is not None and w.take_quiet() is None  # once per quiet moment
    time_s, events, poses = quiet
    assert time_s == pytest.approx(2.5, abs=0.01) and np.array_equal(poses, w.poses())
    assert [(e.a, e.b) for e in events if isinstance(e, Contact)] == [(0, 1)]
    assert poses[1, 0] > 0.05 + 0.02  # pushed off its place ...
    assert np.array_equal(w.odometry()[1], [0.05, 0.0, 0.0])  # ... which its encoders never counted


def test_head_on_movers_slip_their_odometry_runs_ahead_of_the_bodies():
    w = PhysicsWorld(np.array([0, 1]), np.array([[0.0, 0.0, 0.0], [0.03, 0.0, math.pi]]), P, seed=0)
    drive(w, [[0.04, 0.0], [0.04, 0.0]], 1.0)
    odom, true = w.odometry(), w.poses()
    assert abs(odom[0, 0]) > 0.03 and abs(true[0, 0]) < 0.01  # the wheels rolled 3+ cm, the body stalled
    assert true[1, 0] - true[0, 0] >= 2 * P.radius_m - 1e-3


def test_the_world_registry_builds_the_physical_world_with_the_models_body():
    w = make_world("physics", np.array([3, 8]), np.array([[0.0, 0.0, 0.0], [0.2, 0.0, 0.0]]), ModelConfig(robot_radius_m=0.02), 0)
    assert isinstance(w, PhysicsWorld) and w.world.params.radius_m == 0.02
    seen, rho, _ = w.sightings(0)
    assert seen.tolist() == [8] and rho[0] == pytest.approx(0.2, abs=0.05)
    with pytest.raises(SwarmInputError, match="must be finite"):
        w.world.set_twist(3, math.nan, 0.0)


def test_a_world_without_encoders_says_so():
    with World([0], np.zeros((1, 3)), P, seed=0) as w, pytest.raises(SwarmInputError, match="counts no wheel encoders"):
        w.odometry()
