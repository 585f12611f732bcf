"""Robot bodies: the clearance geometry, collision-free plans of every method, contacts of the true motion,
and radius 0 reproducing the point robots' numbers exactly (docs/bodies.md)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from coordinator.clearance import clear_plan
from coordinator.localization import make_localizer
from coordinator.plan import Plan
from coordinator.selection.genetic import GeneticConfig
from coordinator.selection.selector import AnchorSelector, SelectionConfig
from coordinator.simulate import simulate
from runtime.errors import SwarmInputError
from runtime.models.bodies import BodyCheck, closest_approach, impassable_pairs, step_contacts
from runtime.models.config import ModelConfig
from runtime.models.state import SwarmEstimate
from runtime.models.trajectory import Trajectory, body_spacing, min_separation, random_trajectory, validate_passable
from runtime.recording.foxglove_scene import SceneDeriver, schema_errors
from runtime.wire.messages import ContactMessage, TruthSetMessage

R = 0.011
BODIES = ModelConfig()
POINTS = ModelConfig(robot_radius_m=0.0)
FAST = SelectionConfig(samples=4, genetic=GeneticConfig(population=6, generations=2))

# A mover that must cross where another robot stands: robot 0 drives 0.3 m along y = 0 through robot 1,
# which steps 0.12 m aside; robots 2 and 3 barely move. In id order (one-at-a-time) robot 0 goes first.
CROSSING = Trajectory(
    np.arange(4),
    np.array([[0.0, 0.0, 0.0], [0.15, 0.0, 1.0], [0.0, 0.3, 0.0], [0.3, 0.3, 0.0]]),
    np.array([[[0.3, 0.0], [0.15, 0.12], [0.0, 0.32], [0.3, 0.32]]]),
)


def test_closest_approach_is_the_distance_from_the_origin_to_the_relative_segment():
    offset = np.array([[-0.1, 0.01], [0.05, 0.0], [0.3, 0.4], [0.3, 0.4]])
    velocity = np.array([[0.2, 0.0], [0.1, 0.0], [0.0, 0.0], [-0.6, -0.8]])
    # crossing: passes 0.01 m from the origin at s = 0.5; moving away: closest at s = 0; still: |offset|;
    # reaching the origin exactly at s = 0.5 of a 1 m segment
    np.testing.assert_allclose(closest_approach(offset, velocity), [0.01, 0.05, 0.5, 0.0], atol=1e-15)


def test_contacts_are_found_during_the_step_not_only_at_its_ends():
    before = np.array([[0.0, 0.0, 0.0], [0.1, 0.005, 0.0], [0.5, 0.5, 0.0]])
    after = np.array([[0.2, 0.0, 0.0], [9.0, 9.0, 9.0], [0.6, 0.5, 0.0]])  # a still robot's row of ``after`` is not read
    moving = np.array([True, False, True])
    # robot 0 passes robot 1 (still) 5 mm off centre half way; both ends are 0.1 m apart
    [contact] = step_contacts(before, after, moving, R)
    assert (contact.a, contact.b) == (0, 1) and contact.distance == pytest.approx(0.005)
    assert contact.point == pytest.approx((0.1, 0.0025))
    assert step_contacts(before, after, moving, 0.0) == []
    # two movers crossing at right angles at the same time touch; one a quarter step later passes behind
    cross = step_contacts(np.array([[0, -0.1, 0], [-0.1, 0, 0]]), np.array([[0, 0.1, 0], [0.1, 0, 0]]), np.array([True, True]), R)
    late = step_contacts(np.array([[0, -0.1, 0], [-0.15, 0, 0]]), np.array([[0, 0.1, 0], [0.05, 0, 0]]), np.array([True, True]), R)
    assert len(cross) == 1 and cross[0].distance == pytest.approx(0.0, abs=1e-12) and late == []


def test_the_contact_risk_grows_with_the_path_and_the_uncertainty():
    """The chance constraint replaced the 2-sigma margin: a mover passing a still robot 4 cm off its path
    (0.1 m into a 0.3 m drive) is at risk above 1e-3 per step, within 0.1, and more so with an uncertain start."""
    current = np.array([[0.0, 0.0], [0.1, 0.04]])
    check = BodyCheck(BODIES, current, np.array([[0.3, 0.0], [0.1, 0.04]]))
    [conflict] = check.step_conflicts(current, np.array([True, False]))
    assert conflict.closest == pytest.approx(0.04) and conflict.allowed == 1e-3 and 1e-3 < conflict.probability < 0.1
    assert check.with_bound(0.1).step_conflicts(current, np.array([True, False])) == []
    uncertain = BodyCheck(BODIES, current, np.array([[0.3, 0.0], [0.1, 0.04]]), position_var=0.01**2)
    [c] = uncertain.step_conflicts(current, np.array([True, False]))
    assert c.probability > 10 * conflict.probability
    assert BodyCheck(POINTS, current, current + [0.3, 0]).step_conflicts(current, np.array([True, True])) == []


def test_a_mover_crossing_a_robot_waits_for_it_and_the_plan_says_so():
    estimate = SwarmEstimate.isotropic(CROSSING.ids, CROSSING.initial_poses, 0.005, 0.01)
    one_at_a_time = Plan.equal(np.arange(4), 3)
    plan, regrouped = clear_plan(BODIES, one_at_a_time, estimate, CROSSING.configurations[0])
    order = [int(g[0]) for g in plan.groups]
    assert order.index(1) < order.index(0)  # robot 1 steps aside before robot 0 drives through its place
    assert regrouped is not None and regrouped.planned_steps == 4 and not regrouped.unclear
    assert BodyCheck.of_estimate(BODIES, estimate, CROSSING.configurations[0]).is_clear(plan.groups)
    assert clear_plan(POINTS, one_at_a_time, estimate, CROSSING.configurations[0]) == (one_at_a_time, None)


@pytest.mark.parametrize("method", ["one-at-a-time", "ref57", "heuristic-fixed", "no-anchors", "inchworm"])
def test_every_method_runs_the_crossing_without_contact_and_pays_in_steps(method):
    bodies = simulate(CROSSING, method, BODIES, selection=FAST, seed=3)
    points = simulate(CROSSING, method, POINTS, selection=FAST, seed=3)
    assert bodies.contacts(R) == []
    for config in bodies.configs:  # every executed step is clear under the nominal motion it was planned with
        assert config.regrouped is None or not config.regrouped.unclear
    if method != "inchworm":  # fixed groups keep their plan and pay for the split steps; the search may choose another plan
        assert bodies.steps_per_config().sum() == points.steps_per_config().sum() + bodies.steps_added()
    if method == "one-at-a-time":  # robot 0 drives through robot 1 when planned as points
        assert [(c.a, c.b) for c in points.contacts(R)] == [(0, 1)] and bodies.steps_added() == 0


def test_selection_returns_only_collision_free_plans():
    estimate = SwarmEstimate.isotropic(CROSSING.ids, CROSSING.initial_poses, 0.005, 0.01)
    desired = CROSSING.configurations[0]
    check = BodyCheck.of_estimate(BODIES, estimate, desired)
    for seed in range(3):
        selection = AnchorSelector(BODIES, make_localizer("paper", BODIES), FAST, seed=seed).select(estimate, desired)
        assert check.is_clear(selection.plan.groups)
    for n_a in (2, 3):
        scores = AnchorSelector(BODIES, make_localizer("paper", BODIES), replace(FAST, anchor_counts=(n_a,)), seed=1).select(estimate, desired)
        assert check.is_clear(scores.plan.groups)


def test_radius_zero_reproduces_the_point_robot_numbers():
    # P_f of the same runs on the code before bodies (commit 1f0c31b), printed with repr; the last bits follow the
    # BLAS kernels of the CPU (runtime.recording.mcap_log.float_platform), so equal to 1e-12 relative, the same plans
    traj = random_trajectory(8, 4, np.random.default_rng(7))
    for method, pf in (("inchworm", 0.024423905004254565), ("ref57", 0.020555234950629487), ("one-at-a-time", 0.018372817325195565)):
        run = simulate(traj, method, POINTS, selection=FAST, seed=7)
        assert run.pf() == pytest.approx(pf, rel=1e-12, abs=0) and run.steps_added() == 0 and all(c.regrouped is None for c in run.configs)
    assert np.array_equal(random_trajectory(8, 4, np.random.default_rng(7), **body_spacing(POINTS)).configurations, traj.configurations)


def test_overlapping_or_impassable_configurations_are_refused_by_name():
    overlap = Trajectory(np.array([3, 5]), np.array([[0, 0, 0], [0.1, 0, 0]]), np.array([[[0.0, 0.0], [0.015, 0.0]]]))
    with pytest.raises(SwarmInputError, match=r"configuration 1: robots 3 and 5 overlap: centres 0.0150 m apart.*0.022 m"):
        validate_passable(overlap, BODIES)
    swap = Trajectory(np.array([0, 1]), np.array([[0, 0, 0], [0.03, 0, 0]]), np.array([[[0.03, 0.0], [0.0, 0.0]]]))
    with pytest.raises(SwarmInputError, match="configuration 1: robots 0 and 1 cannot reach it without touching"):
        validate_passable(swap, BODIES)
    assert impassable_pairs(swap.initial_poses[:, :2], swap.configurations[0], R).tolist() == [[0, 1]]
    follow = Trajectory(np.array([0, 1]), np.array([[0, 0, 0], [0.03, 0, 0]]), np.array([[[0.03, 0.0], [0.06, 0.0]]]))
    validate_passable(follow, BODIES)  # one behind the other: the leader first, or both together
    validate_passable(swap, POINTS)


def test_random_trajectories_keep_bodies_apart_and_passable():
    for seed in range(4):
        traj = random_trajectory(10, 6, np.random.default_rng(seed), **body_spacing(BODIES))
        validate_passable(traj, BODIES)
        sep = 2 * R + 3 * math.sqrt(2) * 0.3 * math.radians(3)
        assert min(min_separation(c) for c in [traj.initial_poses[:, :2], *traj.configurations]) >= sep - 1e-12


def test_the_scene_draws_bodies_as_discs_and_contacts_as_rings():
    deriver = SceneDeriver(None, robot_radius=R)
    [(topic, scene)] = deriver.derive(TruthSetMessage(run="r", step=1, stamp_ns=5, ids=[0, 1], poses=[[0, 0, 0], [0.1, 0, 0]]))
    import json

    doc = json.loads(scene)
    assert topic == "/foxglove/true" and schema_errors(doc) == []
    assert [e["cylinders"][0]["size"]["x"] for e in doc["entities"]] == [2 * R, 2 * R] and doc["entities"][0]["spheres"] == []
    contact = ContactMessage(run="r", step=2, stamp_ns=6, config=1, a=0, b=1, distance_m=0.01, radius_m=R, point=[0.05, 0.0])
    [(topic, scene)] = deriver.derive(contact)
    doc = json.loads(scene)
    assert topic == "/foxglove/contacts" and schema_errors(doc) == [] and doc["entities"][0]["id"] == "contact/2/0-1"
    points = json.loads(SceneDeriver(None).derive(TruthSetMessage(run="r", step=1, stamp_ns=5, ids=[0], poses=[[0, 0, 0]]))[0][1])
    assert points["entities"][0]["cylinders"] == [] and len(points["entities"][0]["spheres"]) == 1
