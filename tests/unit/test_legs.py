"""Approach legs (coordinator/legs.py, docs/bodies.md): a mover whose straight drive would end too close to a neighbour
for the contact bound stops at a staging point first; a clear drive gets no leg; legs are deterministic, recorded and
carried by checkpoints."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from coordinator.checkpoint import RunState
from coordinator.clearance import Regrouping, clear_plan
from coordinator.executor import InchwormExecutor
from coordinator.legs import (
    END_BOUND,
    LEG_CAP,
    LEG_FRACTIONS,
    MAX_LEGS,
    LegRecord,
    corrections,
    deferred_movers,
    driven_legs,
    first_leg,
    leg_targets,
    new_touches,
    next_leg,
    step_at_risk,
)
from coordinator.localization import make_localizer
from coordinator.plan import Plan
from coordinator.run_result import ConfigRecord
from coordinator.selection.selector import SelectionConfig
from coordinator.simulate import initial_estimate
from coordinator.strategies import make_strategy
from runtime.models.bodies import CONTACT_BOUND, BodyCheck
from runtime.models.config import ModelConfig
from runtime.models.contact_risk import MotionMoments, disc_probability, instant_bound
from runtime.models.simulation import SimulatedSwarm
from runtime.models.state import SwarmEstimate
from runtime.models.trajectory import Trajectory

X3 = ModelConfig(turn_sigma_rad=math.radians(9.0), drive_sigma_frac=0.15)
X558 = ModelConfig(turn_sigma_rad=math.radians(16.74), drive_sigma_frac=0.279)


def estimate(positions: list[list[float]], headings: list[float]) -> SwarmEstimate:
    """Robots at ``positions`` with correlated, anisotropic position covariances (a few mm) and a heading error."""
    n = len(positions)
    cov = np.zeros((n, 3, 3))
    cov[:, :2, :2] = np.array([[4e-5, 2.5e-5], [2.5e-5, 3e-5]])
    cov[:, 2, 2] = math.radians(2.0) ** 2
    cov[:, 0, 2] = cov[:, 2, 0] = 1e-5
    poses = np.column_stack([np.array(positions, float), headings])
    return SwarmEstimate(np.arange(n), poses, cov)


# robot 0 drives 0.3 m towards the still robot 1, whose place is 0.06 m beside its target: at x3 the drive ends with
# about 4.5 cm of error per axis, so the target is within 2 sigma of the neighbour (the bodies need 2.2 cm)
NEAR = estimate([[0.0, 0.0], [0.3, 0.06], [-0.3, 0.3]], [math.pi - 1e-3, -math.pi + 1e-3, 0.5])
NEAR_DESIRED = np.array([[0.3, 0.0], [0.3, 0.06], [-0.3, 0.3]])


def end_risk(cfg: ModelConfig, est: SwarmEstimate, ends: np.ndarray, i: int, j: int) -> float:
    """The contact bound of robot i arrived at ``ends[i]`` (from its estimate) against robot j standing still."""
    m = MotionMoments(cfg, est.positions, np.where(np.arange(len(ends))[:, None] == i, ends, est.positions), est.cov)
    mu, _, sigma, _, _ = m.pairs(np.array([i]), np.array([j]), np.ones(1), np.zeros(1), np.zeros(1), np.zeros(1))
    return float(instant_bound(mu, sigma, 2.0 * cfg.robot_radius_m)[0])


def end_probability(cfg: ModelConfig, est: SwarmEstimate, ends: np.ndarray, i: int, j: int) -> float:
    """The contact probability of robots i and j arrived at ``ends`` (n, 2) from their estimates (no drive: standing)."""
    m = MotionMoments(cfg, est.positions, ends, est.cov)
    mu, _, sigma, _, _ = m.pairs(np.array([i]), np.array([j]), np.ones(1), np.zeros(1), np.ones(1), np.zeros(1))
    return float(disc_probability(mu, sigma, 2.0 * cfg.robot_radius_m)[0])


def test_a_drive_ending_near_a_still_neighbour_stops_short_on_its_way():
    going = np.array([True, False, False])
    assert end_risk(X3, NEAR, NEAR_DESIRED, 0, 1) > 0.01  # straight in: far over the bound
    leg = leg_targets(X3, NEAR, NEAR_DESIRED, going)
    assert leg.staged.tolist() == [True, False, False]
    f = np.hypot(*leg.targets[0]) / 0.3  # on the straight way, short of the target, at one of the fractions
    assert leg.targets[0, 1] == pytest.approx(0.0, abs=1e-12) and min(abs(f - x) for x in LEG_FRACTIONS) < 1e-12
    assert end_risk(X3, NEAR, leg.targets, 0, 1) <= CONTACT_BOUND
    np.testing.assert_array_equal(leg.targets[1:], NEAR.positions[1:])  # the others stand


def test_a_clear_drive_gets_no_leg_and_the_plan_is_clear_plans():
    far = NEAR_DESIRED.copy()
    far[0] = [0.3, -0.4]  # 0.46 m from the neighbour's place
    assert not leg_targets(X3, NEAR, far, np.ones(3, bool)).any
    plan = Plan(np.array([0, 1, 2]), (1, 1, 1))
    cleared, regrouped, leg = first_leg(X3, plan, NEAR, far)
    assert leg is None and (cleared, regrouped) == clear_plan(X3, plan, NEAR, far)
    # point robots drive straight too
    assert not leg_targets(ModelConfig(robot_radius_m=0.0, turn_sigma_rad=X3.turn_sigma_rad), NEAR, NEAR_DESIRED, np.ones(3, bool)).any


def test_a_last_leg_over_against_a_still_neighbour_stops_short_where_the_bound_holds():
    """Its last leg does not drive into a robot that stands for the rest of the change: the robot ends the change at
    the farthest point of its way (in 1/16 steps) whose end keeps the bound, reported as stopped short."""
    leg = leg_targets(X3, NEAR, NEAR_DESIRED, np.ones(3, bool), last=True)
    assert leg.short.tolist() == [True, False, False] and not leg.staged.any() and not leg.held.any()
    f = leg.targets[0, 0] / 0.3
    assert leg.targets[0, 1] == pytest.approx(0.0, abs=1e-12) and 0.0 < f < 1.0 and (16 * f) == pytest.approx(round(16 * f))
    assert end_risk(X3, NEAR, leg.targets, 0, 1) <= CONTACT_BOUND
    farther = leg.targets.copy()
    farther[0, 0] += 0.3 / 16  # the next point of its way is over
    assert end_probability(X3, NEAR, farther, 0, 1) > CONTACT_BOUND


def test_a_way_past_a_still_neighbour_never_ends_a_leg_over_the_bound_and_stops_short_before_it():
    """Robot 0 drives 0.4 m past robot 1, which stands 3 cm beside its way for the rest of the change, at x5.58, the
    legs driven exactly: where every staging point walks into robot 1 it takes a shorter leg that keeps the bound and
    re-plans, and ends the change stopped short where the next step would be over (the way is straight)."""
    est = estimate([[0.0, 0.0], [0.2, 0.03]], [0.1, 2.0])
    desired = np.array([[0.4, 0.0], [0.2, 0.03]])
    _, _, first = first_leg(X558, Plan(np.array([0, 1]), (1, 1)), est, desired)
    assert first is not None
    legs, poses = (first,), est.poses.copy()
    while True:
        ends = poses[:, :2].copy()
        ends[np.searchsorted(est.ids, legs[-1].ids)] = legs[-1].targets
        assert end_probability(X558, SwarmEstimate(est.ids, poses.copy(), est.cov), ends, 0, 1) <= CONTACT_BOUND
        poses[:, :2] = ends
        if not len(legs[-1].going_on):
            break
        leg = next_leg(X558, legs, SwarmEstimate(est.ids, poses.copy(), est.cov), desired, len(legs))
        if leg is None:  # it stops where it stands: no leg drives it
            break
        legs += (leg,)
    assert 0.05 < poses[0, 0] < 0.2 - 2 * X558.robot_radius_m and poses[0, 1] == 0.0
    assert len(legs) <= LEG_CAP


def test_a_target_at_risk_even_reached_without_noise_stops_short_at_a_safe_distance():
    tight = NEAR_DESIRED.copy()
    tight[0] = [0.3, 0.035]  # 2.5 cm from the neighbour with 5-6 mm of position error: even standing there is over the bound
    there = NEAR.poses.copy()
    there[:, :2] = tight
    assert end_probability(X3, SwarmEstimate(NEAR.ids, there, NEAR.cov), tight, 0, 1) > 0.1
    leg = leg_targets(X3, NEAR, tight, np.ones(3, bool))
    assert leg.short.tolist() == [True, False, False]  # its goal is pulled back along its way
    goal = tight[0] * (np.hypot(*leg.targets[0]) / np.hypot(*tight[0]))
    assert leg.targets[0, 0] * tight[0, 1] - leg.targets[0, 1] * tight[0, 0] == pytest.approx(0.0, abs=1e-12)  # on its way
    there[0, :2] = goal
    assert end_probability(X3, SwarmEstimate(NEAR.ids, there, NEAR.cov), there[:, :2], 0, 1) <= CONTACT_BOUND
    assert not leg_targets(ModelConfig(robot_radius_m=0.0), NEAR, tight, np.ones(3, bool)).any  # point robots: never at risk


def test_legs_are_deterministic_and_the_next_starts_from_the_new_estimate():
    plan = Plan(np.array([2, 0, 1]), (2, 1))
    a = first_leg(X3, plan, NEAR, NEAR_DESIRED)
    b = first_leg(X3, plan, NEAR, NEAR_DESIRED)
    assert a[2] is not None and b[2] is not None
    np.testing.assert_array_equal(a[2].targets, b[2].targets)
    assert a[0] == b[0] or np.array_equal(a[0].order, b[0].order)
    first = a[2]
    # re-localized at the staging point: the rest of the way is short, so it ends within the bound
    moved = NEAR.poses.copy()
    moved[0, :2] = first.targets[0]
    after = SwarmEstimate(NEAR.ids, moved, NEAR.cov)
    leg = next_leg(X3, (first,), after, NEAR_DESIRED, 1)
    again = next_leg(X3, (first,), after, NEAR_DESIRED, 1)
    assert leg is not None and again is not None
    assert leg.ids.tolist() == [0] and leg.plan.groups[0].tolist() == [0]
    np.testing.assert_array_equal(leg.targets, again.targets)
    last = next_leg(X3, (first,) * (MAX_LEGS - 1), after, NEAR_DESIRED, MAX_LEGS - 1)  # its MAX_LEGS-th driven leg
    assert last is not None and not last.staged.any() and not len(last.going_on)
    # the rest of the way still ends over the bound against the still robot 1: it ends the change short, on its way
    assert end_probability(X3, after, NEAR_DESIRED, 0, 1) > CONTACT_BOUND
    assert first.targets[0, 0] < last.targets[0, 0] < NEAR_DESIRED[0, 0] and last.targets[0, 1] == 0.0
    ends = after.positions.copy()
    ends[0] = last.targets[0]
    assert end_probability(X3, after, ends, 0, 1) <= CONTACT_BOUND
    assert next_leg(X3, (first,), after.select(np.array([False, True, True])), NEAR_DESIRED[1:], 1) is None  # lost


# robots 0 and 1 drive 0.3 m side by side into places 0.07 m apart next to the still robot 2
SIDE = Trajectory(np.arange(3), np.array([[0.0, 0.0, 0.0], [0.0, 0.1, 0.0], [0.35, 0.2, 0.0]]),
                  np.array([[[0.3, 0.0], [0.3, 0.1], [0.35, 0.2]]]))


def run(cfg: ModelConfig, checkpoints: list[RunState] | None = None):
    loc = make_localizer("paper", cfg)
    ex = InchwormExecutor(SimulatedSwarm(SIDE.ids, SIDE.initial_poses, cfg, 3), loc,
                          make_strategy("one-at-a-time", SIDE.n, cfg, loc, SelectionConfig(), 3), cfg,
                          on_checkpoint=None if checkpoints is None else checkpoints.append)
    return ex.run(SIDE, initial_estimate(SIDE, 3, 0.005, math.radians(1.0)))


def test_the_executor_drives_the_legs_and_counts_their_steps():
    states: list[RunState] = []
    result = run(X3, states)
    [config] = result.configs
    assert config.legs and config.legs[0].plan is config.plan and config.staging_stops >= 1
    assert config.n_steps == len(result.steps) == config.plan.n_steps + sum(leg.plan.n_steps for leg in config.legs[1:])
    assert result.steps_added() == config.n_steps - 3 and result.staging_stops() == config.staging_stops
    # the first leg's movers were commanded towards their staging points, not their targets
    first = config.legs[0]
    staged = first.staged_ids.tolist()
    step = next(s for s in result.steps if s.moving[staged[0]])
    assert step.commands[staged[0], 1] == pytest.approx(np.hypot(*(first.targets[staged[0]] - result.initial_estimate.positions[staged[0]])))
    assert not result.contacts(X3.robot_radius_m)
    # a checkpoint inside a later leg carries the legs bit for bit
    inside = next(s for s in states if len(s.legs) > 1 and s.group == 0)
    back = RunState.from_json(inside.to_json(), SIDE, result.initial_estimate)
    assert len(back.legs) == len(inside.legs) and all(
        np.array_equal(a.targets, b.targets) and np.array_equal(a.staged, b.staged) and np.array_equal(a.ids, b.ids)
        and a.plan.key() == b.plan.key() for a, b in zip(back.legs, inside.legs, strict=True))
    assert back.to_json() == inside.to_json()
    # default noise: the straight drives end at 2.9e-4, within the steps' bound but over END_BOUND: one staging stop
    # each; at 0.7 x the default noise (4.4e-6) every drive clears, no legs, and the state is written as before
    default = ModelConfig()
    assert END_BOUND < end_probability(default, result.initial_estimate, SIDE.configurations[0], 0, 1) < CONTACT_BOUND
    assert run(default).staging_stops() == 2
    calm = run(replace(default, turn_sigma_rad=0.7 * default.turn_sigma_rad, drive_sigma_frac=0.7 * default.drive_sigma_frac))
    assert calm.staging_stops() == 0 and not calm.configs[0].legs and calm.steps_added() == 0


def test_a_staging_point_is_checked_against_the_others_again():
    # at x3 robot 0 drives 0.4 m along y = 0 past the still robots 2, 3 and 4 (6 cm beside its target and its 0.75 and
    # 0.5 staging points), so only its shortest leg keeps clear of them, and that one ends next to robot 1's way: both
    # at their shortest staging points are still over the bound, so they are separated in time: robot 0 (the longer
    # way) waits where it stands and robot 1 drives its short way straight to its goal (clear of robot 0 standing)
    est = estimate([[0.0, 0.0], [0.1, 0.06], [0.4, 0.06], [0.3, 0.06], [0.2, 0.06]], [0.0, -math.pi + 1e-3, 1.0, 2.0, 3.0])
    desired = np.array([[0.4, 0.0], [0.1, 0.03], [0.4, 0.06], [0.3, 0.06], [0.2, 0.06]])
    leg = leg_targets(X3, est, desired, np.array([True, True, False, False, False]))
    assert leg.held.tolist() == [True, False, False, False, False] and not leg.staged.any()
    assert leg.targets[0].tolist() == [0.0, 0.0] and leg.targets[1].tolist() == pytest.approx([0.1, 0.03])
    assert end_probability(X3, est, leg.targets, 0, 1) <= CONTACT_BOUND


class Died(Exception):
    """The coordinator died right after publishing a checkpoint."""


def test_a_run_resumed_from_a_checkpoint_inside_any_leg_ends_bit_for_bit_as_the_uninterrupted_one():
    states: list[RunState] = []
    clean = run(X3, states)
    def first(test) -> int:
        return next(k for k, s in enumerate(states) if s.legs and s.plan is not None and test(len(s.legs), s.group, s.plan.n_steps))

    # inside the first leg; a later leg just planned, half driven, and driven to its end before the next is planned
    inside = [first(lambda n, g, steps: n == 1 and g == 1), first(lambda n, g, steps: n > 1 and g == 0),
              first(lambda n, g, steps: n > 1 and 0 < g < steps), first(lambda n, g, steps: n > 1 and g == steps)]
    start = clean.initial_estimate
    for k in inside:
        backend = SimulatedSwarm(SIDE.ids, SIDE.initial_poses, X3, 3)  # the robots outlive the coordinator
        seen: list[RunState] = []

        def die_at_k(s: RunState, seen: list[RunState] = seen, k: int = k) -> None:
            seen.append(s)
            if len(seen) == k + 1:
                raise Died

        loc = make_localizer("paper", X3)
        with pytest.raises(Died):
            InchwormExecutor(backend, loc, make_strategy("one-at-a-time", SIDE.n, X3, loc, SelectionConfig(), 3), X3,
                             on_checkpoint=die_at_k).run(SIDE, start)
        taken = RunState.from_json(seen[-1].to_json(), SIDE, start)
        loc = make_localizer("paper", X3)
        resumed = InchwormExecutor(backend, loc, make_strategy("one-at-a-time", SIDE.n, X3, loc, SelectionConfig(), 3),
                                   X3).run(SIDE, start, resume=taken)
        assert len(resumed.steps) == len(clean.steps), k
        for a, b in zip(resumed.steps, clean.steps, strict=True):
            np.testing.assert_array_equal(a.estimate.poses, b.estimate.poses)
            np.testing.assert_array_equal(a.truth, b.truth)
        [got], [want] = resumed.configs, clean.configs
        assert got.n_steps == want.n_steps and got.staging_stops == want.staging_stops and len(got.legs) == len(want.legs)
        assert all(np.array_equal(a.targets, b.targets) and a.plan.key() == b.plan.key() for a, b in zip(got.legs, want.legs, strict=True))
        assert resumed.pf() == clean.pf() and resumed.steps_added() == clean.steps_added()


def test_the_fault_bench_finds_a_run_with_legs_identical_to_its_own_json():
    """``swarm bench faults`` compares a distributed run's ``--json`` rows with the in-process run: a configuration's
    ``steps`` there count its legs' steps, and so must the comparison (it compared the first leg's plan alone, so
    every run with legs was reported not identical)."""
    from inchworm.bench.faults import same_table
    from inchworm.simulation import run_json

    result = run(X3)
    [config] = result.configs
    assert config.n_steps > config.plan.n_steps  # legs added steps
    summary = json.loads(json.dumps(run_json(result, "one-at-a-time", "paper", 3, [], None, X3.robot_radius_m)))
    assert same_table(summary, result)
    summary["configs"][0]["steps"] = config.plan.n_steps
    assert not same_table(summary, result)


# robot 0 drives to a place 2.5 cm from the still robot 1 (bodies need 2.2 cm): at risk even without motion
TIGHT = Trajectory(np.arange(3), np.array([[0.0, 0.0, math.pi - 1e-3], [0.3, 0.06, -math.pi + 1e-3], [0.35, 0.2, 0.0]]),
                   np.array([[[0.3, 0.035], [0.3, 0.06], [0.35, 0.2]]]))


def test_a_target_at_risk_without_motion_is_stopped_short_and_reported():
    from inchworm.simulation import contacts_json, summary_text

    loc = make_localizer("paper", X3)
    ex = InchwormExecutor(SimulatedSwarm(TIGHT.ids, TIGHT.initial_poses, X3, 3), loc,
                          make_strategy("one-at-a-time", TIGHT.n, X3, loc, SelectionConfig(), 3), X3)
    result = ex.run(TIGHT, initial_estimate(TIGHT, 3, 0.005, math.radians(1.0)))
    assert result.stopped_short() == [[0]] and not result.contacts(X3.robot_radius_m)
    final = result.configs[0].legs[-1].targets[0]
    assert 0.2 < np.hypot(*final) < np.hypot(0.3, 0.035)  # short of its target on its way, at a safe distance
    assert np.hypot(*(result.configs[0].truth[0, :2] - result.configs[0].truth[1, :2])) > 2 * X3.robot_radius_m
    keys = contacts_json(result, X3.robot_radius_m)
    assert keys["stopped_short"] == 1 and keys["legs"][0]["stopped_short"] == [0]
    assert "robots [0] stopped short of their targets" in summary_text(result, "one-at-a-time", "paper", X3.robot_radius_m)


# at x5.58 robots 0 and 1 drive 0.30 and 0.20 m on converging ways into places 9 cm apart: even both at their shortest
# staging points (a quarter of the way) the pair is over the bound (1.3e-3), which is where they used to drive anyway
CONVERGE = estimate([[0.0, 0.0], [0.05, 0.1]], [-1.0, -0.7])
CONVERGE_DESIRED = np.array([[0.3, 0.05], [0.25, 0.13]])


def test_a_converging_pair_is_separated_in_time_the_longer_way_waits():
    shortest = CONVERGE.positions + LEG_FRACTIONS[-1] * (CONVERGE_DESIRED - CONVERGE.positions)
    assert end_probability(X558, CONVERGE, shortest, 0, 1) > CONTACT_BOUND
    leg = leg_targets(X558, CONVERGE, CONVERGE_DESIRED, np.ones(2, bool))
    assert leg.held.tolist() == [True, False] and leg.staged.tolist() == [False, True]
    assert leg.targets[0].tolist() == CONVERGE.positions[0].tolist()  # it waits where it stands
    assert end_probability(X558, CONVERGE, leg.targets, 0, 1) <= CONTACT_BOUND
    there = CONVERGE.poses.copy()  # and the leg's end keeps the bound at the waiting robot's goal, where it goes later
    there[0, :2] = CONVERGE_DESIRED[0]
    ends = leg.targets.copy()
    ends[0] = CONVERGE_DESIRED[0]
    assert end_probability(X558, SwarmEstimate(CONVERGE.ids, there, CONVERGE.cov), ends, 0, 1) <= CONTACT_BOUND


def test_the_same_robot_keeps_waiting_until_the_pair_is_clear_and_the_change_ends():
    """Legs driven exactly (each robot arrives at its leg's target, its covariance as before): robot 0 waits in a first
    run of legs (until robot 1 is far enough ahead) and never again, robot 1 never waits, somebody drives in every leg,
    and both end at their goals within LEG_CAP legs."""
    plan = Plan(np.array([0, 1]), (2,))
    _, _, first = first_leg(X558, plan, CONVERGE, CONVERGE_DESIRED)
    assert first is not None and first.held.tolist() == [0] and first.plan.n_robots == 2  # waiting in the first leg: a zero move
    legs, poses = (first,), CONVERGE.poses.copy()
    while len(legs[-1].going_on):
        poses[np.searchsorted(CONVERGE.ids, legs[-1].ids), :2] = legs[-1].targets
        leg = next_leg(X558, legs, SwarmEstimate(CONVERGE.ids, poses.copy(), CONVERGE.cov), CONVERGE_DESIRED, len(legs))
        assert leg is not None and not np.isin(leg.held, leg.ids).any() and len(leg.ids)  # somebody drives in every leg
        legs += (leg,)
    poses[np.searchsorted(CONVERGE.ids, legs[-1].ids), :2] = legs[-1].targets
    waits = [0 in leg.held for leg in legs]
    assert 1 <= sum(waits) and waits == sorted(waits, reverse=True)  # a first run of legs, no alternation
    assert not any(1 in leg.held for leg in legs)
    np.testing.assert_allclose(poses[:, :2], CONVERGE_DESIRED)
    assert len(legs) <= LEG_CAP and driven_legs(legs, CONVERGE.ids).max() <= MAX_LEGS


def test_a_robot_over_against_a_waiting_one_waits_too_not_against_a_still_one():
    # robot 2 drives 0.32 m along y = -0.06 from behind robot 0: its shortest staging point is over against robot 0
    # standing there; robot 3 stands still beside robot 1's goal: robot 1 approaches it and does not wait for it
    est = estimate([[0.0, 0.0], [0.05, 0.1], [-0.12, -0.06], [0.25, 0.2]], [-1.0, -0.7, 0.4, 2.0])
    desired = np.array([[0.3, 0.05], [0.25, 0.13], [0.2, -0.06], [0.25, 0.2]])
    leg = leg_targets(X558, est, desired, np.array([True, True, True, False]))
    assert leg.held.tolist() == [True, False, True, False] and leg.staged.tolist() == [False, True, False, False]
    np.testing.assert_array_equal(leg.targets[[0, 2, 3]], est.positions[[0, 2, 3]])


def test_correlated_positions_decide_who_waits():
    """The pair's relative position reads the joint covariance's cross terms: ends 13 cm apart after 7.5 cm drives are
    within END_BOUND for uncorrelated robots (9.6e-5: both stage) and correlated ones (6.4e-5), over it for
    anti-correlated ones (1.3e-4: one waits)."""
    est = estimate([[0.0, 0.0], [0.0, 0.14]], [-1.0, -0.7])
    desired = np.array([[0.3, 0.03], [0.3, 0.14]])
    got = []
    for rho in (0.0, 0.9, -0.9):
        joint = np.kron(np.array([[1.0, rho], [rho, 1.0]]), est.cov[0])
        leg = leg_targets(X558, SwarmEstimate(est.ids, est.poses, est.cov, joint), desired, np.ones(2, bool))
        got.append((leg.held.tolist(), leg.staged.tolist()))
    assert got[0] == got[1] == ([False, False], [True, True])
    assert sorted(got[2][0]) == [False, True] and got[2][1] == [not h for h in got[2][0]]


def test_a_head_on_pair_with_clear_ends_drives_straight_and_the_last_leg_never_waits():
    # robots 0 and 1 pass each other 4 cm apart on their ways: their staging points would be close, their goals are not
    est = estimate([[0.0, 0.0], [0.12, 0.03]], [0.1, math.pi - 0.1])
    desired = np.array([[0.3, 0.0], [-0.1, 0.04]])
    leg = leg_targets(X558, est, desired, np.ones(2, bool))
    assert not leg.any and leg.targets.tolist() == desired.tolist()
    _, _, first = first_leg(X558, Plan(np.array([0, 1]), (2,)), CONVERGE, CONVERGE_DESIRED)
    assert first is not None and first.held.tolist() == [0]
    final = next_leg(X558, (first,) * (LEG_CAP - 1), CONVERGE, CONVERGE_DESIRED, LEG_CAP - 1)
    assert final is not None and not len(final.held) and not final.staged.any()
    # robot 0, which would wait, ends the change where it stands (stopped short); robot 1 drives to its goal
    assert final.ids.tolist() == [1] and final.targets.tolist() == [CONVERGE_DESIRED[1].tolist()]
    last = leg_targets(X558, CONVERGE, CONVERGE_DESIRED, np.ones(2, bool), final=True)
    assert last.short.tolist() == [True, False] and last.targets[0].tolist() == CONVERGE.positions[0].tolist()


def test_when_every_robot_would_wait_the_one_least_at_risk_drives():
    """Robot 0 waits for robot 1 (its way passes 4 cm from robot 1's place), robot 2 on its last leg for robot 1 (its
    goal is robot 1's place), robot 1 against the waiting robot 0: nobody would drive. Not the robot with the shortest
    way (robot 2, into robot 1 standing: 0.76) drives, but robot 1, away from robot 2, at the least risk of the three."""
    est = estimate([[-0.086, -0.716], [-0.128, -0.738], [-0.114, -0.77]], [2.8, 1.5, 1.6])
    desired = np.array([[-0.244, -0.656], [-0.13, -0.478], [-0.124, -0.738]])
    leg = leg_targets(X558, est, desired, np.ones(3, bool), last=np.array([False, False, True]))
    assert leg.held.tolist() == [True, False, True] and leg.staged.tolist() == [False, True, False]
    assert end_probability(X558, est, leg.targets, 1, 2) <= CONTACT_BOUND
    assert end_probability(X558, est, leg.targets, 0, 1) < 0.02
    straight = est.positions.copy()
    straight[2] = desired[2]
    assert end_probability(X558, est, straight, 1, 2) > 0.5


def test_a_checkpoint_carries_the_waiting_robots():
    _, _, first = first_leg(X558, Plan(np.array([0, 1]), (2,)), CONVERGE, CONVERGE_DESIRED)
    assert first is not None
    from coordinator.checkpoint import _from_legs, _legs_json

    data = json.loads(json.dumps(_legs_json((first,))))
    assert data["legs"][0]["held"] == [0]
    [back] = _from_legs(data)
    assert back.held.tolist() == [0] and back.going_on.tolist() == first.going_on.tolist() == [0, 1]
    plain = LegRecord(first.plan, first.ids, first.targets, first.staged, first.regrouped)
    assert "held" not in _legs_json((plain,))["legs"][0]  # no waiting robot: the state is written as before


# robot 0 stands 2.5 cm from robot 1 by its estimate (the bodies need 2.2 cm) after the change's last leg, 6.5 cm short
# of its goal on the far side: touching, or nearly, and standing so for the rest of the change unless it is corrected
TOUCHING = estimate([[0.0, 0.0], [0.025, 0.0], [0.4, 0.4]], [0.3, -2.0, 1.0])
TOUCHING_DESIRED = np.array([[-0.04, 0.0], [0.025, 0.0], [0.4, 0.4]])


def arrived(est: SwarmEstimate, desired: np.ndarray) -> LegRecord:
    """A change's leg after which every robot of ``est`` has arrived (nobody goes on)."""
    n = len(est.ids)
    return LegRecord(Plan(np.arange(n), (n,)), est.ids, desired, np.zeros(n, bool))


def test_a_pair_left_standing_over_the_bound_gets_a_correction_leg_towards_the_goal():
    """After the change's last leg nobody goes on, but robot 0 stands over the bound against robot 1 by the new
    estimate: it drives back towards its goal in one more leg (robot 1, at its goal, and robot 2, far, do not)."""
    assert end_probability(X3, TOUCHING, TOUCHING.positions, 0, 1) > 0.1
    going = np.zeros(3, bool)
    assert corrections(X3, TOUCHING, TOUCHING_DESIRED, going).tolist() == [True, False, False]
    first = arrived(TOUCHING, TOUCHING_DESIRED)
    assert not len(first.going_on)
    leg = next_leg(X3, (first,), TOUCHING, TOUCHING_DESIRED, 1)
    assert leg is not None and leg.ids.tolist() == [0] and leg.plan.groups[0].tolist() == [0]
    ends = TOUCHING.positions.copy()
    ends[0] = leg.targets[0]
    assert leg.targets[0, 0] < 0.0 and leg.targets[0, 1] == pytest.approx(0.0, abs=1e-12)  # on its way, away from robot 1
    assert end_probability(X3, TOUCHING, ends, 0, 1) <= CONTACT_BOUND
    # nobody at risk, or point robots: the change ends as before
    apart = SwarmEstimate(TOUCHING.ids, np.vstack([[-0.04, 0.0, 0.3], TOUCHING.poses[1:]]), TOUCHING.cov)
    assert next_leg(X3, (first,), apart, TOUCHING_DESIRED, 1) is None
    assert next_leg(ModelConfig(robot_radius_m=0.0), (first,), TOUCHING, TOUCHING_DESIRED, 1) is None
    assert not corrections(ModelConfig(robot_radius_m=0.0), TOUCHING, TOUCHING_DESIRED, going).any()


def test_no_correction_where_moving_to_the_goal_does_not_help():
    """A pair over the bound whose robots stand at their goals (a correction has nowhere to go), or a robot whose goal
    is no farther from the neighbour than where it stands, is left standing: no leg that drives nobody."""
    at_goals = TOUCHING_DESIRED.copy()
    at_goals[0] = TOUCHING.positions[0]
    first = arrived(TOUCHING, at_goals)
    assert not corrections(X3, TOUCHING, at_goals, np.zeros(3, bool)).any()
    assert next_leg(X3, (first,), TOUCHING, at_goals, 1) is None
    closer = at_goals.copy()
    closer[0] = [0.004, 0.0]  # 4 mm towards robot 1
    assert not corrections(X3, TOUCHING, closer, np.zeros(3, bool)).any()


def test_a_leg_end_within_the_contact_bound_but_over_the_end_bound_stages_first():
    """Robot 0 drives 0.3 m to a place 16.5 cm beside robot 1's: the straight drive ends at 4.5e-4 at x3, within the
    steps' bound but over END_BOUND: it stops at a staging point first (cheap); on its last leg it drives in (no wait,
    not stopped short: the end keeps CONTACT_BOUND)."""
    est = estimate([[0.0, 0.0], [0.3, 0.165], [-0.3, 0.3]], [math.pi - 1e-3, -math.pi + 1e-3, 0.5])
    desired = np.array([[0.3, 0.0], [0.3, 0.165], [-0.3, 0.3]])
    assert END_BOUND < end_probability(X3, est, desired, 0, 1) <= CONTACT_BOUND
    leg = leg_targets(X3, est, desired, np.ones(3, bool))
    assert leg.staged.tolist() == [True, False, False] and not leg.short.any() and not leg.held.any()
    last = leg_targets(X3, est, desired, np.ones(3, bool), last=True)
    assert not last.any and last.targets.tolist() == desired.tolist()
    farther = desired.copy()
    farther[1, 1] = 0.19  # 7.5e-5 at the end: straight in
    assert not leg_targets(X3, est, farther, np.ones(3, bool)).any


def test_the_change_s_last_leg_stops_short_of_a_standing_robot_instead_of_driving_in():
    """In the LEG_CAP-th leg nobody waits and every robot drives to its goal, but not into a robot that stands for the
    rest of the change: over CONTACT_BOUND against it, it stops short where the bound holds (as on its last leg)."""
    leg = leg_targets(X3, NEAR, NEAR_DESIRED, np.ones(3, bool), final=True)
    assert leg.short.tolist() == [True, False, False] and not leg.staged.any() and not leg.held.any()
    assert 0.0 < leg.targets[0, 0] < NEAR_DESIRED[0, 0] and end_probability(X3, NEAR, leg.targets, 0, 1) <= CONTACT_BOUND


def test_a_correction_is_counted_per_robot_and_leg():
    first = arrived(TOUCHING, TOUCHING_DESIRED)
    leg = next_leg(X3, (first,), TOUCHING, TOUCHING_DESIRED, 1)
    assert leg is not None
    rec = ConfigRecord(0, first.plan, None, TOUCHING, None, legs=(first, leg))
    assert rec.corrections == 1 and rec.holds == 0
    staged = LegRecord(first.plan, first.ids, first.targets, np.array([True, False, False]))
    assert ConfigRecord(0, first.plan, None, TOUCHING, None, legs=(staged, leg)).corrections == 0  # it went on: no correction


def test_a_way_through_a_standing_robot_stops_short_before_it_though_its_end_is_clear():
    """Robot 0's last leg drives 0.3 m along y = 0 to a goal 15 cm past robot 1, which stands 1 cm beside the way for
    the rest of the change: the end keeps the bound (7.8e-4), the way does not (the regrouping would have moved it
    anyway, alone): it stops short before robot 1, where its way keeps the steps' bound."""
    est = estimate([[0.0, 0.0], [0.15, 0.01], [-0.3, 0.3]], [0.0, 1.0, 0.5])
    desired = np.array([[0.3, 0.0], [0.15, 0.01], [-0.3, 0.3]])
    going = np.array([True, False, False])
    assert end_probability(X3, est, desired, 0, 1) < CONTACT_BOUND
    check = BodyCheck.of_estimate(X3, est, desired)
    assert [(c.a, c.b) for c in check.step_conflicts(est.positions, going)] == [(0, 1)]
    leg = leg_targets(X3, est, desired, going, last=True)
    assert leg.short.tolist() == [True, False, False] and 0.0 < leg.targets[0, 0] < 0.15 - 2 * X3.robot_radius_m
    ends = est.positions.copy()
    ends[0] = leg.targets[0]
    assert not BodyCheck.of_estimate(X3, est, ends).step_conflicts(est.positions, going)


def test_two_robots_left_touching_never_both_wait_there():
    """Robot 1 stands touching robot 0 (2.1 mm of overlap between the 2.2 cm bodies); robot 0 waits for robot 2, whose
    way converges with its own, and robot 1's shortest staging point is still over the bound against robot 0 standing:
    it waited too before, the two standing touching for the whole leg (their pair at 0.49 at its end). Waiting helps
    nobody where the pair is at risk already: robot 1 drives away (or robot 0 does), the pair's end far lower."""
    est = estimate([[0.0, 0.0], [0.0, 0.021], [0.35, 0.25]], [0.0, 1.5, -1.5])
    desired = np.array([[0.35, 0.0], [0.05, 0.08], [0.38, 0.03]])
    standing = end_probability(X558, est, est.positions, 0, 1)
    assert standing > 0.4
    leg = leg_targets(X558, est, desired, np.ones(3, bool))
    assert leg.held.sum() == 1 and not leg.held[[0, 1]].all()
    assert end_probability(X558, est, leg.targets, 0, 1) < 0.01 * standing


def test_a_staging_point_over_the_end_bound_against_a_standing_robot_is_taken_shorter_where_one_keeps_it():
    """Robot 0 drives 0.4 m along y = 0 past robot 1, which stands 3 cm beside the way 0.2 m ahead for the rest of the
    change, at x5.58: its shortest staging point (a quarter of the way) ends at 5.9e-4, within the steps' bound but over
    END_BOUND. It stages shorter, at the farthest 1/16 of its way whose end keeps END_BOUND, as it would against a
    robot that drives on. Where no shorter point keeps it (robot 1 4.5 cm beside the way, 6 cm ahead, at x3), it stages
    where CONTACT_BOUND holds, as before: a staging point never ends the change."""
    est = estimate([[0.0, 0.0], [0.2, 0.03], [-0.3, 0.3]], [0.1, 2.0, 0.5])
    desired = np.array([[0.4, 0.0], [0.2, 0.03], [-0.3, 0.3]])
    going = np.array([True, False, False])
    quarter = desired.copy()
    quarter[0] = [0.1, 0.0]
    assert END_BOUND < end_probability(X558, est, quarter, 0, 1) <= CONTACT_BOUND
    leg = leg_targets(X558, est, desired, going)
    assert leg.staged.tolist() == [True, False, False] and not leg.short.any() and not leg.held.any()
    f = leg.targets[0, 0] / 0.4
    assert leg.targets[0, 1] == 0.0 and 0.0 < f < 0.25 and 16 * f == pytest.approx(round(16 * f))
    assert end_probability(X558, est, leg.targets, 0, 1) <= END_BOUND
    farther = leg.targets.copy()
    farther[0, 0] += 0.4 / 16
    assert end_probability(X558, est, farther, 0, 1) > END_BOUND
    # no shorter point keeps END_BOUND: the first 1/16 of the way, within CONTACT_BOUND, as before
    est = estimate([[0.0, 0.0], [0.06, 0.045], [-0.3, 0.3]], [0.1, 2.0, 0.5])
    desired[1] = [0.06, 0.045]
    leg = leg_targets(X3, est, desired, going)
    assert leg.staged.tolist() == [True, False, False] and not leg.short.any()
    assert leg.targets[0].tolist() == [0.4 / 16, 0.0]
    assert END_BOUND < end_probability(X3, est, leg.targets, 0, 1) <= CONTACT_BOUND


def test_a_way_through_a_robot_that_only_corrects_its_place_waits_for_it():
    """Robot 0's last leg drives 17.9 cm to its goal, its straight way passing robot 1, which drives a 7.7 mm correction
    in the same leg: robot 0's drive is over the steps' bound against robot 1 both where it stands and where it
    arrives, so no order of the steps helps (the regrouping moved it anyway: a contact at x3, a configuration of the
    collisions bench). It does not drive there in this leg: it waits, robot 1 corrects, and the next leg judges its way
    against robot 1 standing for the rest of the change."""
    est = estimate([[0.0878, 0.0152], [0.1175, -0.0157], [-0.3, 0.3]], [-0.4, 1.0, 0.5])
    desired = np.array([[0.2531, -0.0528], [0.1203, -0.0229], [-0.3, 0.3]])
    going = np.array([True, True, False])
    check = BodyCheck.of_estimate(X3, est, desired)
    risks = check.pair_risks(np.array([0]))
    start, end, _ = risks.over(check.robot_levels())
    assert (start & end).tolist() == [True, False] and risks.j.tolist() == [1, 2]
    leg = leg_targets(X3, est, desired, going, last=np.array([True, True, False]))
    assert leg.held.tolist() == [True, False, False] and not leg.short.any()
    assert leg.targets[1].tolist() == desired[1].tolist()
    # robot 1 corrected and standing for the rest of the change: robot 0's way past it is judged as any standing robot's
    poses = est.poses.copy()
    poses[1, :2] = desired[1]
    there = SwarmEstimate(est.ids, poses, est.cov)
    after = leg_targets(X3, there, desired, np.array([True, False, False]), last=True)
    ends = there.positions.copy()
    ends[0] = after.targets[0]
    assert not BodyCheck.of_estimate(X3, there, ends).step_conflicts(there.positions, np.array([True, False, False]))


def test_a_step_is_judged_again_against_robots_its_leg_moved_before_it():
    """Robot 1 drives 0.2 m along y = 0 in the leg's second step; robot 0 drove in its first and was planned 15 cm
    beside the way, but its drive's error left it 2.5 cm from it (angles near +-pi): the step is over the bound against
    robot 0 where the new estimate puts it. Not where robot 0 did not move in the leg (the regrouping judged it where
    it stands), nor far from the way, nor for point robots."""
    est = estimate([[0.1, 0.025], [0.0, 0.0], [-0.3, 0.3]], [math.pi - 1e-3, -math.pi + 1e-3, 0.5])
    targets = np.array([[0.1, 0.15], [0.2, 0.0], [-0.3, 0.3]])
    moving, moved = np.array([False, True, False]), np.array([True, False, False])
    assert step_at_risk(X3, est, targets, moving, moved)
    assert not step_at_risk(X3, est, targets, moving, np.zeros(3, bool))
    far = estimate([[0.1, 0.15], [0.0, 0.0], [-0.3, 0.3]], [math.pi - 1e-3, -math.pi + 1e-3, 0.5])
    assert not step_at_risk(X3, far, targets, moving, moved)
    assert not step_at_risk(ModelConfig(robot_radius_m=0.0), est, targets, moving, moved)
    # as a leg's plan: group 1 (robots 1 and 3) after group 0 (robot 0): robot 1 stands in it (robot 3, far from both,
    # drives); after the last group nothing is left to judge, and a pair the leg's regrouping already could not clear
    # is no news
    est4 = estimate([[0.1, 0.025], [0.0, 0.0], [-0.3, 0.3], [0.4, -0.3]], [math.pi - 1e-3, -math.pi + 1e-3, 0.5, 0.0])
    targets4 = np.array([[0.1, 0.15], [0.2, 0.0], [-0.3, 0.3], [0.5, -0.3]])
    plan = Plan(np.array([0, 1, 2]), (1, 2))  # rows of the leg's ids [0, 1, 3]
    leg = LegRecord(plan, np.array([0, 1, 3]), targets4[[0, 1, 3]], np.zeros(3, bool))
    assert deferred_movers(X3, est4, leg, 0).tolist() == [1]
    assert deferred_movers(X3, est4, leg, 1).tolist() == []
    assert deferred_movers(X3, est4, replace(leg, regrouped=Regrouping(plan, (0, 1), 0.1)), 0).tolist() == []
    # robot 3 right beside robot 1's place: driving, it would pass robot 1 standing there: it stands too
    est4 = estimate([[0.1, 0.025], [0.0, 0.0], [-0.3, 0.3], [0.0, 0.08]], [math.pi - 1e-3, -math.pi + 1e-3, 0.5, 0.0])
    targets4[3] = [0.0, -0.08]
    leg = LegRecord(plan, np.array([0, 1, 3]), targets4[[0, 1, 3]], np.zeros(3, bool))
    assert deferred_movers(X3, est4, leg, 0).tolist() == [1, 3]


def test_a_new_touch_is_a_pair_a_mover_left_touching_not_one_at_risk_before():
    # robots 0 and 1 stand 1.9 cm apart (bodies need 2.2 cm) before and after: at risk by design, no new touch; robot 2
    # drove from 10 cm to 2.0 cm beside the still robot 3: a new touch; headings near +-pi do not matter
    before = estimate([[0.0, 0.0], [0.019, 0.0], [0.3, 0.1], [0.3, 0.0]], [math.pi - 1e-3, -math.pi + 1e-3, 0.5, -0.5])
    after = estimate([[0.0, 0.0], [0.019, 0.0], [0.3, 0.02], [0.3, 0.0]], [-math.pi + 1e-3, math.pi - 1e-3, 0.5, -0.5])
    a, b, p = new_touches(X3, before, after, np.array([0, 2]))
    assert (a.tolist(), b.tolist()) == ([2], [3]) and p[0] > CONTACT_BOUND
    turned = SwarmEstimate(after.ids, after.poses + [0.0, 0.0, 2 * math.pi - 2e-3], after.cov)
    assert new_touches(X3, before, turned, np.array([0, 2]))[2].tolist() == p.tolist()
    assert not len(new_touches(X3, before, after, np.array([0, 1]))[0])  # nobody of the new pair moved
    assert not len(new_touches(replace(X3, robot_radius_m=0.0), before, after, np.array([2]))[0])  # point robots
    # robot 3 lost during the step: left out
    assert not len(new_touches(X3, before, after.select(np.array([True, True, True, False])), np.array([2]))[0])


def test_a_leg_cut_by_a_touch_counts_the_steps_run_and_its_other_robots_go_on():
    from coordinator.checkpoint import _from_legs, _legs_json

    ids = np.array([3, 5, 7, 9])
    plan = Plan(np.array([2, 0, 3, 1]), (1, 2, 1))  # groups [7], [3, 9], [5]
    leg = LegRecord(plan, ids, np.zeros((4, 2)), np.array([False, True, False, False]), held=np.array([9]), groups_run=2)
    assert leg.cut and leg.n_steps == 2 and leg.ran.tolist() == [True, False, True, True]
    assert leg.going_on.tolist() == [5, 9]  # staged and not run, waiting
    assert driven_legs((leg,), ids).tolist() == [1, 0, 1, 0]  # 5's group was not run, 9 waited
    whole = replace(leg, groups_run=None)
    assert not whole.cut and whole.n_steps == 3 and whole.going_on.tolist() == [5, 9]
    rec = ConfigRecord(0, plan, None, SwarmEstimate.isotropic(ids, np.zeros((4, 3)), 0.01, 0.1), None, ids, None, (leg,))
    assert rec.n_steps == 2 and rec.legs_cut == 1 and rec.staging_stops == 0  # robot 5 never drove to its stop
    [back] = _from_legs(json.loads(json.dumps(_legs_json((leg,)))))
    assert back.groups_run == 2 and back.plan.key() == plan.key() and back.held.tolist() == [9]
    old = _legs_json((whole,))
    assert "groups_run" not in old["legs"][0] and _from_legs(old)[0].groups_run is None  # as written before the cut
