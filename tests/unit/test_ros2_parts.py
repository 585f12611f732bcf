"""The ROS 2 driver's parts that need no ROS 2 graph: the kinematic world, velocity profiles, sensing windows, settings,
and the one-line answer of the ROS 2 commands without the ``ros2`` extra."""

from __future__ import annotations

import math
import sys

import numpy as np
import pytest

from inchworm.launcher import DriverOptions, LaunchOptions, SwarmOptions, ros2_settings, ros2_step_timeout
from robot_agent.ros2_config import Ros2Config, SightingWindow, closed_loop_speed, velocity_profile
from runtime.errors import SwarmInputError
from runtime.models.config import ModelConfig
from runtime.models.motion import apply_motion, execute_command
from runtime.models.rng import Stream, robot_rng
from runtime.models.sensing import sense_robot
from runtime.models.trajectory import Trajectory
from runtime.models.world import KinematicWorld, make_world
from swarm_cli.main import main

NS = 1_000_000_000


def drive(world: KinematicWorld, k: int, turn: float, dist: float, dt: float, vmax=(2.0, 1.5), amax=(8.0, 3.0)) -> None:
    """Robot ``k`` of ``world`` executes (turn, dist) as the ROS 2 driver does: a turn profile, a drive profile, then rest."""
    n = len(world.ids)
    for speeds, col in ((velocity_profile(turn, vmax[0], amax[0], dt), 1), (velocity_profile(dist, vmax[1], amax[1], dt), 0)):
        for v in speeds:
            twists = np.zeros((n, 2))
            twists[k, col] = v
            world.step(dt, twists)
    world.step(dt, np.zeros((n, 2)))


@pytest.mark.parametrize("turn, dist, heading", [(3.1, 0.4, -3.1), (-0.2, 0.0, 3.14159), (0.0, 0.25, 0.3), (-3.1415, 1e-4, -1e-9)])
def test_a_profiled_command_ends_where_the_motion_model_puts_it(turn, dist, heading):
    """Same seed, same robot: the world's segment noise is execute_command's draw, applied when the turn ends."""
    cfg = ModelConfig(turn_sigma_rad=math.radians(9.0), drive_sigma_frac=0.15)
    start = np.array([[0.3, -0.2, heading], [1.0, 1.0, 0.0]])
    world = KinematicWorld(np.array([4, 7]), start, cfg, seed=11)
    drive(world, 0, turn, dist, dt=0.02)
    drive(world, 0, -turn / 2, dist / 3, dt=0.01)
    want = execute_command(start[0], np.array([turn, dist]), cfg, rng := robot_rng(11, 4, Stream.MOTION))
    want = execute_command(want, np.array([-turn / 2, dist / 3]), cfg, rng)
    assert np.allclose(world.poses()[0, :2], want[:2], atol=1e-9)
    assert abs(math.remainder(world.poses()[0, 2] - want[2], 2 * math.pi)) < 1e-9
    odom = apply_motion(apply_motion(start[0], np.array([turn, dist])), np.array([-turn / 2, dist / 3]))
    assert np.allclose(world.odometry()[0, :2], odom[:2], atol=1e-9)  # the encoders see no slip
    assert np.array_equal(world.poses()[1], start[1]) and list(world.segments) == [2, 0]  # robot 7 never moved: no draw


def test_sightings_are_the_sensing_model_with_the_robots_stream():
    cfg = ModelConfig(range_sigma_m=0.02, dropout_prob=0.3)
    poses = np.array([[0.0, 0.0, 3.1], [0.3, 0.01, 0.0], [-0.2, -0.2, 1.0], [5.0, 5.0, 0.0]])
    world = make_world("kinematic", np.array([2, 5, 9, 11]), poses, cfg, seed=3)
    rng = robot_rng(3, 2, Stream.SENSING)
    for _ in range(3):
        ids, rho, phi = world.sightings(0)
        nb, want_rho, want_phi = sense_robot(poses, 0, cfg, rng)
        assert ids.tolist() == [[2, 5, 9, 11][i] for i in nb] and np.array_equal(rho, want_rho) and np.array_equal(phi, want_phi)
    with pytest.raises(SwarmInputError, match="^world rigid: not one of kinematic, physics"):
        make_world("rigid", np.array([0]), np.zeros((1, 3)), cfg, 0)


@pytest.mark.parametrize("distance, vmax, amax, dt", [(0.3, 0.2, 0.5, 0.05), (-2.5, 1.0, 4.0, 0.02), (1e-4, 1.0, 2.0, 0.05), (3.14, 6.0, 30.0, 0.01)])
def test_velocity_profiles_cover_the_distance_within_the_limits(distance, vmax, amax, dt):
    v = velocity_profile(distance, vmax, amax, dt)
    assert v.sum() * dt == pytest.approx(distance, rel=1e-12)
    assert np.all(np.sign(v) == np.sign(distance)) and np.abs(v).max() <= vmax * (1 + 1e-9) + amax * dt
    dv = np.diff(np.concatenate([[0.0], np.abs(v), [0.0]]))
    assert np.abs(dv).max() <= amax * dt * 1.5 + 1e-12  # a trapezoid sampled at the middle of each period
    assert velocity_profile(0.0, vmax, amax, dt).size == 0


@pytest.mark.parametrize("target, vmax, amax, dt, lag", [(0.4, 0.2, 0.5, 0.05, 0), (3.1, 1.0, 2.0, 0.05, 3), (0.002, 1.5, 6.0, 0.02, 2),
                                                      (1.0, 0.2, 0.5, 0.05, 6)])
def test_closing_on_delayed_odometry_arrives_at_the_target(target, vmax, amax, dt, lag):
    """The odometry comes ``lag`` periods late (transport, a busy machine); counting the speeds sent since as done, as
    the driver does, the motion ends on the target, within the limits."""
    moved, speeds = [0.0], []
    for k in range(10_000):
        pending = sum(speeds[len(speeds) - lag:]) * dt if lag else 0.0
        v = closed_loop_speed(target - moved[max(0, len(moved) - 1 - lag)] - pending, k * dt, vmax, amax, dt)
        if v == 0.0:
            break
        speeds.append(v)
        moved.append(moved[-1] + v * dt)
    assert moved[-1] == pytest.approx(target, abs=1e-12)
    assert max(speeds) <= vmax and np.all(np.diff(speeds[: len(speeds) // 2]) <= amax * dt + 1e-12)
    assert closed_loop_speed(-0.1, 1.0, vmax, amax, dt) == 0.0 and closed_loop_speed(1.0, 0.0, vmax, amax, dt) == min(vmax, amax * dt)


def test_what_the_odometry_cannot_show_yet_counts_every_speed_until_it_was_replaced():
    from robot_agent.ros2_driver import _unseen

    sent = [(0, 0.5), (50_000_000, -1.0), (200_000_000, 0.25)]  # the second held 150 ms (the sender woke up late)
    assert _unseen(sent, 100_000_000, 300_000_000) == pytest.approx(1.0 * 0.1 + 0.25 * 0.1)
    assert _unseen(sent, -1, 200_000_000) == pytest.approx(0.5 * 0.05 + 1.0 * 0.15) and _unseen([], 0, 10) == 0.0


def test_the_driver_motion_time_bounds_its_profiles():
    cfg = Ros2Config.load({"rate_hz": "20", "settle_s": "0.1"})
    want = (len(velocity_profile(math.pi, 1.0, 2.0, 0.05)) + len(velocity_profile(1.0, 0.2, 0.5, 0.05))) * 0.05 + 0.1
    assert cfg.motion_time_s(math.pi, 1.0) == pytest.approx(want) and 9.0 < want < 9.3  # 3.65 s turn + 5.4 s drive + settle


def test_a_sensing_window_keeps_the_newest_sighting_of_each_robot_taken_in_it():
    w = SightingWindow(3, (0, 1, 3, 4), "robot{id}/base_link")
    t0 = 100 * NS
    w.add(t0 - 1, "robot3/base_link", "robot1/base_link", 9.0, 9.0)  # taken while moving, arrives late
    w.add(t0 + 5, "robot3/base_link", "robot1/base_link", -0.3, -1e-12)  # bearing just below -pi
    w.add(t0 + 5, "robot3/base_link", "robot1/base_link", -0.3, -1e-12)  # the same sighting twice
    w.add(t0 + 2, "/robot3/base_link", "robot0/base_link", 0.1, 0.1)
    w.add(t0 + 9, "robot3/base_link", "robot0/base_link", 0.0, 0.2)  # newer: wins
    w.add(t0 + 3, "robot3/base_link", "robot3/base_link", 0.1, 0.0)  # itself
    w.add(t0 + 3, "robot3/base_link", "robot7/base_link", 0.1, 0.0)  # not in the run
    w.add(t0 + 3, "robot4/base_link", "robot0/base_link", 0.1, 0.0)  # another observer's sighting
    w.add(t0 + 3, "robot3/base_link", "robot4/base_link", math.nan, 0.0)
    w.add(t0 + 3, "robot3/base_link", "camera", 0.1, 0.0)
    ids, rho, phi = w.observations(t0)
    assert ids.tolist() == [0, 1]
    assert np.allclose(rho, [0.2, 0.3]) and phi[0] == pytest.approx(math.pi / 2)
    assert -math.pi <= phi[1] < math.pi and abs(abs(phi[1]) - math.pi) < 1e-9
    assert w.dropped == {"itself": 1, "a robot not in the run": 1, "another observer's frame": 1, "not finite": 1, "child frame of no robot": 1}
    assert w.observations(t0 + 10)[0].size == 0  # a later window: nothing seen in it yet


def test_settings_from_a_file_and_options(tmp_path):
    path = tmp_path / "lab.toml"
    path.write_text('namespace = "/tb3_{id}"\nframe = "tb3_{id}/base_footprint"\n[topics]\nground_truth = "mocap"\n'
                    '[limits]\nmax_linear_speed = 0.22\n[qos]\ncmd_vel = "best_effort"\ndepth = 5\n[namespaces]\n3 = "/spare"\n')
    cfg = Ros2Config.load({"config": str(path), "limits.max_angular_speed": "2.84", "silence_s": "0.5"})
    assert (cfg.namespace_of(1), cfg.namespace_of(3), cfg.frame_of(2)) == ("/tb3_1", "/spare", "tb3_2/base_footprint")
    assert (cfg.ground_truth, cfg.max_linear_speed, cfg.max_angular_speed, cfg.silence_s, cfg.cmd_vel_qos, cfg.depth) == (
        "mocap", 0.22, 2.84, 0.5, "best_effort", 5)
    assert Ros2Config.load({}) == Ros2Config()


@pytest.mark.parametrize("text, options, message", [
    ("[limits]\nmax_speed = 1\n", {}, r"\[limits\] has no setting 'max_speed'"),
    ("speed = 1\n", {}, "unknown key 'speed'"),
    ("[limits\n", {}, "not TOML"),
    ("", {"max_linear_speed": "fast"}, "max_linear_speed=fast: not a number"),
    ("", {"max_linear_speed": "-1"}, "max_linear_speed must be a number > 0"),
    ("", {"warp": "9"}, "^driver_option warp: not a setting of the ROS 2 driver"),
    ("", {"qos.cmd_vel": "sometimes"}, "qos cmd_vel must be reliable or best_effort"),
    ('frame = "base_link"\n', {}, "frame must contain {id}"),
])
def test_bad_settings_are_one_line_naming_the_key(tmp_path, text, options, message):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(SwarmInputError, match=message):
        Ros2Config.load({"config": str(path), **options})
    with pytest.raises(SwarmInputError, match="cannot read it"):
        Ros2Config.load({"config": str(tmp_path / "missing.toml")})


def test_the_bridge_highlights_the_robots_that_stood_still_and_draws_two_sigma_ellipses():
    from inchworm.ros2_bridge import anchors_of, ellipse
    from runtime.wire.messages import PlanMessage

    plan = PlanMessage(run="r", step=3, config=2, n_anchors=2, groups=((1, 2), (0,)))
    ids = np.array([0, 1, 2, 3])
    assert anchors_of(plan, 3, ids) == {0, 3} and anchors_of(plan, 4, ids) == {1, 2, 3}
    assert anchors_of(plan, 5, ids) == set() and anchors_of(plan, 2, ids) == set() and anchors_of(None, 3, ids) == set()
    cov = np.array([[4e-4, 3.9e-4], [3.9e-4, 4e-4]])  # strongly correlated
    pts = ellipse(cov)
    assert np.allclose(np.einsum("ni,ij,nj->n", pts, np.linalg.inv(cov), pts), 4.0) and np.allclose(pts[0], pts[-1])
    assert np.allclose(ellipse(np.zeros((2, 2))), 0.0)  # a robot known exactly: a point, not NaN


@pytest.mark.parametrize("argv", [["ros2", "robots", "--trajectory", "t.json"], ["ros2", "bridge", "--run", "r"],
                                  ["launch", "--driver", "ros2", "-n", "3", "--configs", "1"], ["launch", "--ros2", "-n", "3", "--configs", "1"]])
def test_without_ros2_the_commands_name_the_extra(monkeypatch, capsys, tmp_path, argv):
    monkeypatch.setitem(sys.modules, "rclpy", None)  # import rclpy -> ImportError, as without the extra
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "needs ROS 2" in err[0] and "pip install 'inchworm-swarm[ros2]'" in err[0], err


@pytest.mark.parametrize("extra, message", [
    (["--physics-param", "radius_m=0.02"], "--physics-param, --run and --hub are for the physical world: they need --world physics"),
    (["--world", "physics", "--hub", "tcp/127.0.0.1:1"], "--hub names the Zenoh endpoint of a run: it needs --run RUN"),
    (["--world", "physics", "--physics-param", "mass_kg=heavy"], "--physics-param mass_kg=heavy: 'heavy' is not a number"),
    (["--world", "rigid"], "--world rigid: not one of kinematic, physics"),
    (["--world", "physics", "--run", "nosuchrun-x"], "--run nosuchrun-x: no live run of that id on this host (give --hub ENDPOINT)"),
])
def test_ros2_robots_world_options_are_checked_in_one_line(capsys, tmp_path, extra, message):
    pytest.importorskip("rclpy")
    pytest.importorskip("pymunk")
    traj = tmp_path / "t.json"
    Trajectory(np.arange(2), np.array([[0.0, 0.0, 0.0], [0.2, 0.0, 0.0]]), np.array([[[0.1, 0.0], [0.3, 0.0]]])).save(traj)
    assert main(["ros2", "robots", "--trajectory", str(traj), *extra]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0], err


def test_launch_gives_the_ros2_driver_the_wheels_limits_of_the_physical_world():
    """Defaults above the wheels' limits become them; what the lab set stays (the robots then say it exceeds the wheels)."""
    pytest.importorskip("pymunk")
    o = LaunchOptions(swarm=SwarmOptions(world="physics", physics_params=("max_wheel_speed_m_s=0.1",)),
                      driver=DriverOptions(name="ros2", ros2_robots=True, options=("linear_accel=0.4",)))
    options, truth = ros2_settings(o)
    assert truth and options[0] == "max_linear_speed=0.1" and "linear_accel=0.4" in options and "ground_truth=ground_truth" in options
    assert not any(o.startswith(("max_angular_speed", "angular_accel")) for o in options)  # 1 rad/s, 2 rad/s^2: within the wheels
    assert ros2_step_timeout(options) > ros2_step_timeout(["ground_truth=ground_truth"])  # slower wheels, longer steps


def test_launch_in_the_physical_world_drives_simulated_ros2_robots_only(capsys, tmp_path, monkeypatch):
    """A lab's ROS 2 robots are not in the physical world: --world physics needs --ros2-robots (one line, exit 2)."""
    pytest.importorskip("pymunk")
    monkeypatch.chdir(tmp_path)
    assert main(["launch", "--driver", "ros2", "--world", "physics", "-n", "3", "--configs", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].endswith(
        "--world physics drives simulated or emulated robots: it needs the driver sim or gateway, or ros2 with ros2_robots, got ros2"), err
