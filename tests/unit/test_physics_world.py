"""The physical world (runtime.world): wheel limits, contacts that push, stalls, occlusion, determinism by seed."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pymunk")

from runtime.errors import OptionError, SwarmInputError
from runtime.models.config import ModelConfig
from runtime.world.params import PhysicsParams, parse_physics_params
from runtime.world.physics import Contact, Stuck, World
from runtime.world.profiles import Trapezoid, TurnDriveProfile
from runtime.world.sensing import visible

P = PhysicsParams()


@pytest.mark.parametrize("distance", [0.0, 1e-4, 0.004, 0.3])
def test_trapezoid_travels_its_distance_within_the_limits(distance):
    tr = Trapezoid(distance, 0.05, 0.25)
    t = np.linspace(-0.1, tr.duration + 0.1, 200001)
    v = tr.speed(t)
    assert v.max() <= 0.05 + 1e-12
    assert np.abs(np.diff(v)).max() <= 0.25 * (t[1] - t[0]) + 1e-12
    assert np.trapezoid(v, t) == pytest.approx(distance, rel=1e-4, abs=1e-9)


def test_turn_then_drive_wheels_turn_in_place_then_roll_together():
    prof = TurnDriveProfile(-math.pi + 1e-9, 0.1, P.track_m, P.max_wheel_speed_m_s, P.max_wheel_accel_m_s2)
    left, right = prof.wheels(prof.turn.duration / 2)
    assert left == -right and left > 0  # a clockwise turn near -pi
    left, right = prof.wheels(prof.turn.duration + prof.drive.duration / 2)
    assert left == right == pytest.approx(P.max_wheel_speed_m_s)


def test_a_lone_robot_goes_roughly_where_it_was_sent():
    with World([7], np.array([[0.2, -0.1, 3.1]]), P, seed=3) as w:
        w.command(7, 0.3, 0.15)
        w.settle()
        x, y, h = w.pose(7)
        heading = 3.1 + 0.3
        assert math.hypot(x - 0.2 - 0.15 * math.cos(heading), y + 0.1 - 0.15 * math.sin(heading)) < 0.02
        assert not w.busy() and w.at_rest() and w.take_events() == []


def test_wheel_speed_and_acceleration_limits_hold_also_when_blocked():
    w = World([0, 1, 2], np.array([[0.0, 0.0, 0.0], [0.04, 0.0, math.pi], [0.0, 0.05, -math.pi / 2]]), P, seed=0)
    w.command(0, 0.0, 0.2)
    w.command(1, 0.0, 0.2)
    w.command(2, math.pi - 1e-6, 0.1)
    speeds = []
    while w.busy() and w.time_s < 30:
        w.step()
        speeds.append([*w.wheel_speeds(0), *w.wheel_speeds(1), *w.wheel_speeds(2)])
    s = np.array(speeds)
    assert np.abs(s).max() <= P.max_wheel_speed_m_s + 1e-12
    assert np.abs(np.diff(s, axis=0)).max() <= P.max_wheel_accel_m_s2 * P.dt_s + 1e-12
    w.set_wheel_speeds(0, 9.0, -9.0)  # clipped
    w.step(400)
    assert w.wheel_speeds(0) == (P.max_wheel_speed_m_s, -P.max_wheel_speed_m_s)


def test_a_contact_pushes_a_standing_robot_out_of_its_place():
    start = np.array([[0.0, 0.0, 0.0], [0.1, 0.008, 1.0]])
    w = World([0, 1], start, P, seed=4)
    w.command(0, 0.0, 0.2)
    w.settle()
    assert np.linalg.norm(w.pose(1)[:2] - start[1, :2]) > 0.01  # the anchor was shoved (the mover pushes harder than it holds)
    contacts = [e for e in w.take_events() if isinstance(e, Contact)]
    assert contacts and (contacts[0].a, contacts[0].b) == (0, 1) and contacts[0].impulse_n_s > 0
    assert 0.08 < contacts[0].point[0] < 0.1


def test_crossing_movers_push_each_other_off_their_paths():
    start = np.array([[0.0, 0.0, 0.0], [0.1, -0.1, math.pi / 2]])
    alone = World([0, 1], start + [[0, 0, 0], [5.0, 0, 0]], P, seed=4)  # robot 1 far away: the same draws, no contact
    w = World([0, 1], start, P, seed=4)
    for world in (alone, w):
        world.command(0, 0.0, 0.2)
        world.command(1, 0.0, 0.2)
        world.settle()
    assert np.linalg.norm(w.pose(0)[:2] - alone.pose(0)[:2]) > 0.01
    assert np.linalg.norm(w.pose(1)[:2] - alone.pose(1)[:2] - [5.0, 0]) > 0.01
    assert [(e.a, e.b) for e in w.take_events()][:1] == [(0, 1)] and alone.take_events() == []
    d = np.linalg.norm(w.pose(0)[:2] - w.pose(1)[:2])
    assert d >= 2 * P.radius_m * 0.98  # bodies never pass through each other


def test_head_on_movers_stall_and_are_reported_stuck():
    w = World([3, 5], np.array([[0.0, 0.0, 0.0], [0.06, 0.0, math.pi]]), P, seed=1)
    w.command(3, 0.0, 0.2)
    w.command(5, 0.0, 0.2)
    w.settle()
    events = w.take_events()
    stuck = {e.robot: e for e in events if isinstance(e, Stuck)}
    assert set(stuck) == {3, 5}
    assert all(e.achieved_m < 0.05 and e.commanded_m > 0.18 for e in stuck.values())
    gap = np.linalg.norm(w.pose(3)[:2] - w.pose(5)[:2])
    assert gap == pytest.approx(2 * P.radius_m, abs=1e-3)
    touching = [e for e in events if isinstance(e, Contact)]
    assert len(touching) == 1 and touching[0].end_s is None  # still pressed together
    w.command(3, math.pi, 0.05)  # it backs away: the ongoing contact is not reported twice
    w.settle()
    assert not [e for e in w.take_events() if isinstance(e, Contact) and e.end_s is None]


def test_a_robot_driving_into_a_row_of_standing_robots_stalls_against_them():
    """Each standing robot holds with hold_mu m g; four in a row hold more than the mover's traction transmits."""
    poses = np.array([[0.0, 0.0, 0.0]] + [[0.05 + 0.0221 * k, 0.0, 1.0] for k in range(4)])
    w = World(range(5), poses, P, seed=0)
    w.command(0, 0.0, 0.2)
    w.settle()
    assert [(e.robot, e.achieved_m < 0.04) for e in w.take_events() if isinstance(e, Stuck)] == [(0, True)]
    np.testing.assert_allclose(w.poses()[1:, :2], poses[1:, :2], atol=2e-3)  # the row barely gave way
    assert w.pose(0)[0] == pytest.approx(0.05 - 2 * P.radius_m, abs=1e-3)  # pressed against the first one


def test_occlusion_and_field_of_view_remove_sightings():
    poses = np.array([[0.0, 0.0, 0.0], [0.05, 0.002, 0.0], [0.12, -0.001, 0.0], [-0.1, 0.0, 0.0], [0.0, 0.6, 0.0]])
    seen, rho, phi = visible(poses, 0, P)
    assert seen.tolist() == [1, 3]  # 2 hidden behind 1, 4 out of range
    assert rho[1] == pytest.approx(0.1) and abs(phi[1]) == pytest.approx(math.pi)
    assert visible(poses, 0, PhysicsParams(occlusion=False))[0].tolist() == [1, 2, 3]
    assert visible(poses, 0, PhysicsParams(fov_rad=math.pi))[0].tolist() == [1]  # 3 is behind it
    with World(range(5), poses, P, seed=0) as w:
        ids, ranges, bearings = w.sense(0)
        assert ids.tolist() == [1, 3] and np.all(ranges > 0)


def test_same_seed_same_world_other_seed_other_world():
    def run(seed):
        poses = np.array([[0.0, 0.0, 0.2], [0.05, 0.01, 2.0], [0.03, -0.04, -1.0], [0.09, 0.0, math.pi]])
        w = World([0, 1, 2, 3], poses, P, seed=seed)
        for k, (turn, drive) in enumerate([(0.1, 0.1), (-2.5, 0.07), (1.9, 0.08), (0.0, 0.06)]):
            w.command(k, turn, drive)
        w.settle()
        return w.poses(), w.take_events(), [w.sense(k) for k in range(4)]

    a, b, c = run(11), run(11), run(12)
    assert np.array_equal(a[0], b[0]) and a[1] == b[1]
    assert all(np.array_equal(x, y) for sa, sb in zip(a[2], b[2], strict=True) for x, y in zip(sa, sb, strict=True))
    assert not np.array_equal(a[0], c[0])


def test_bad_input_names_what_is_wrong():
    with pytest.raises(SwarmInputError, match="robot 9 is not in the world"):
        World([0], np.zeros((1, 3))).command(9, 0.0, 0.1)
    with pytest.raises(SwarmInputError, match="must be finite"):
        World([0], np.zeros((1, 3))).command(0, math.nan, 0.1)
    with pytest.raises(SwarmInputError, match="distinct"):
        World([1, 1], np.zeros((2, 3)))
    w = World([0], np.zeros((1, 3)))
    w.close()
    with pytest.raises(SwarmInputError, match="closed"):
        w.step()
    with pytest.raises(SwarmInputError, match="unknown physics parameter"):
        parse_physics_params(["mass=1"], ModelConfig())
    with pytest.raises(SwarmInputError, match="fov_rad must be at most"):
        parse_physics_params(["fov_rad=7"], ModelConfig())
    p = parse_physics_params(["mass_kg=0.02", "occlusion=false"], ModelConfig(robot_radius_m=0.02, sensing_range_m=0.3))
    assert (p.mass_kg, p.occlusion, p.radius_m, p.sensing_range_m) == (0.02, False, 0.02, 0.3)


def test_an_in_process_run_in_the_physical_world_is_reproducible_and_not_the_model():
    from inchworm import simulate

    a, b = (simulate(robots=5, configs=1, method="no-anchors", seed=2, world="physics") for _ in range(2))
    model = simulate(robots=5, configs=1, method="no-anchors", seed=2)
    assert np.array_equal(a.true_configurations(), b.true_configurations()) and a.world_events == b.world_events
    assert not np.allclose(a.true_configurations(), model.true_configurations())
    assert a.pf() == b.pf() and 0 < a.pf() < 1 and model.world_events == []


def test_without_pymunk_the_commands_name_the_extra(monkeypatch, capsys):
    from swarm_cli.main import main

    monkeypatch.setitem(__import__("sys").modules, "pymunk", None)
    assert main(["sim", "--world", "physics", "--robots", "4", "--configs", "1", "--baseline", "none"]) == 2
    assert capsys.readouterr().err.strip() == ("swarm sim: error: the physical world needs pymunk 7: "
                                               "pip install 'inchworm-swarm[physics]'")
    assert main(["launch", "--world", "physics"]) == 2
    assert "pip install 'inchworm-swarm[physics]'" in capsys.readouterr().err


def test_a_physics_agent_process_hosts_every_robot_of_the_run():
    from robot_agent.assembly import AgentSpec, build_agents
    from runtime.models.trajectory import random_trajectory
    from runtime.wire.transport import ZenohSettings

    traj = random_trajectory(3, 1, np.random.default_rng(0))
    spec = AgentSpec(ZenohSettings("client", connect=("tcp/127.0.0.1:7447",)), "r", [0, 1], None, trajectory=traj, physics=P)
    with pytest.raises(OptionError, match=r"host them all in this process \(hosted 0-2\), got hosted 0-1") as caught:
        build_agents(spec)
    assert caught.value.flag_message().endswith("host them all in this process (--id 0-2), got --id 0-1")
    example = f"{Path(__file__).resolve().parents[2] / 'examples' / 'drivers' / 'unicycle.py'}:UnicycleDriver"
    with pytest.raises(SwarmInputError, match="needs driver sim, got driver .*unicycle.py:UnicycleDriver"):
        build_agents(AgentSpec(ZenohSettings("client", connect=("tcp/127.0.0.1:7447",)), "r", [0, 1, 2], None, trajectory=traj,
                               physics=P, driver=example))


def test_world_events_become_physics_event_messages():
    from robot_agent.physics_driver import physics_events
    from runtime.wire.messages import PhysicsEvent, decode, encode

    w = World([3, 5], np.array([[0.0, 0.0, 0.0], [0.06, 0.0, math.pi]]), P, seed=1)
    w.command(3, 0.0, 0.2)
    w.command(5, 0.0, 0.2)
    w.settle()
    msgs = physics_events("r1", 4, w.time_s, w.take_events(), w.ids, w.poses())
    assert [m.kind for m in msgs] == ["contact", "stuck", "stuck", "poses"]
    contact, poses = msgs[0], msgs[-1]
    assert contact.robots == (3, 5) and contact.ongoing == 1 and contact.duration_s == pytest.approx(w.time_s - contact.time_s)
    assert poses.time_s == w.time_s and np.array_equal(np.array(poses.poses), w.poses()) and poses.step == 4
    assert all(decode(encode(m), PhysicsEvent) == m for m in msgs)
