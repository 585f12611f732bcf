"""Bodies of large swarms: the k-d tree's candidate pairs give exactly the checks of every pair, and regrouping
moves robots that go in order in waves that stay clear (docs/bodies.md)."""

from dataclasses import astuple

import numpy as np
import pytest

import runtime.models.bodies as bodies
from runtime.models.bodies import BodyCheck, impassable_pairs, step_contacts
from runtime.models.config import ModelConfig
from runtime.models.trajectory import body_spacing, random_trajectory

CFG = ModelConfig()
R = CFG.robot_radius_m


def rough_change(n: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A crowded change of ``n`` robots: random positions, a few pairs touching exactly (2R apart, at the start and
    at the end), crossing and swapping paths, long and zero drives; uneven position and heading variances."""
    rng = np.random.default_rng(seed)
    current = rng.uniform(0.0, 0.07 * np.sqrt(n), (n, 2))
    desired = current + rng.normal(0.0, 0.08, (n, 2)) * rng.choice([0.0, 1.0, 4.0], (n, 1), p=[0.1, 0.8, 0.1])
    for a in range(0, min(n, 12), 4):  # touching bodies, at the start and where they arrive
        angle = rng.uniform(-np.pi, np.pi)
        current[a + 1] = current[a] + 2 * R * np.array([np.cos(angle), np.sin(angle)])
        desired[a + 3] = desired[a + 2] + 2 * R * np.array([np.cos(angle), np.sin(angle)])
    desired[20], desired[21] = current[21].copy(), current[20].copy()  # a swap: the paths cross head on
    position_var = rng.uniform(0.0, 2e-4, n) * rng.choice([0.0, 1.0], n)
    heading_var = rng.uniform(0.0, 1e-3, n)
    return current, desired, position_var, heading_var


def checks(current: np.ndarray, desired: np.ndarray, position_var: np.ndarray, heading_var: np.ndarray,
           seed: int) -> tuple:
    """Every body check of a change, as plain values."""
    rng = np.random.default_rng(seed)
    n = len(current)
    check = BodyCheck(CFG, current, desired, position_var, heading_var)
    moving = rng.random(n) < 0.5
    before = np.where((rng.random(n) < 0.3)[:, None], desired, current)
    groups = np.array_split(rng.permutation(n), 3)
    risks = check.pair_risks(np.arange(n))
    levels = rng.choice([1e-3, 1e-2, 1e-1], n)
    relations = [sorted(zip(risks.i[bad].tolist(), risks.j[bad].tolist(), strict=True)) for bad in risks.over(levels)]
    regrouped = check.regroup(groups)
    ordered = check.with_bound(1e-2).ordered_moves(groups[0], rng.random(n) < 0.3, np.arange(n) % 2)
    truth = desired + rng.normal(0.0, 0.01, desired.shape)
    return ([astuple(c) for c in check.step_conflicts(before, moving)],
            [astuple(c) for c in step_contacts(before, truth, moving, R)],
            impassable_pairs(current, desired, R).tolist(), relations,
            [g.tolist() for g in regrouped.groups], regrouped.unclear, regrouped.bound,
            [g.tolist() for g in ordered[0]], ordered[1])


@pytest.mark.parametrize("seed", [0, 1])
def test_the_indexed_checks_equal_the_checks_of_every_pair(monkeypatch, seed):
    change = rough_change(160, seed)
    monkeypatch.setattr(bodies, "INDEX_MIN", 10**9)  # every pair
    every = checks(*change, seed)
    monkeypatch.setattr(bodies, "INDEX_MIN", 0)  # the k-d tree's candidates
    indexed = checks(*change, seed)
    assert indexed == every
    assert every[0] and every[1] and every[2] and all(every[3])  # conflicts, contacts, a swap and each relation were found


def test_a_touching_pair_is_a_contact_and_a_conflict_either_way(monkeypatch):
    """A mover grazing a still robot (centres 2R apart at the closest) touches and is a conflict; a pair that already
    touches where it stands is a contact but not a conflict (no plan can do better than the configuration)."""
    start = np.array([[0.0, 0.0], [0.1, 2 * R - 1e-6], [1.0, 1.0], [1.0 + 2 * R - 1e-6, 1.0]])
    end = start + np.array([[0.2, 0.0], [0.0, 0.0], [0.0, 0.1], [0.0, 0.0]])
    for index_min in (10**9, 0):
        monkeypatch.setattr(bodies, "INDEX_MIN", index_min)
        moving = np.array([True, False, True, False])
        assert [(c.a, c.b) for c in step_contacts(start, end, moving, R)] == [(0, 1), (2, 3)]
        conflicts = BodyCheck(CFG, start, end).step_conflicts(start, moving)
        assert [(c.a, c.b) for c in conflicts] == [(0, 1)] and conflicts[0].probability > 0.5


def test_robots_that_go_in_order_move_in_clear_waves():
    traj = random_trajectory(120, 1, np.random.default_rng(0), sensing_range=CFG.sensing_range_m, **body_spacing(CFG))
    current, desired = traj.initial_poses[:, :2], traj.configurations[0]
    check = BodyCheck(CFG, current, desired, 1e-4, 1e-3)
    out = check.regroup([np.arange(120)])  # all at once: a few pairs cross, so robots go in order
    assert sorted(np.concatenate(out.groups).tolist()) == list(range(120))
    # in waves, not one at a time; two robots, one following the other closely, keep no bound up to 0.1 in any
    # order with a 1 cm start uncertainty (the 2-sigma margin lowered to the bare 2R for them): they go one at a time
    assert 1 < len(out.groups) < 30 and len(out.unclear) <= 2
    level = check.with_bound(out.bound)
    before = current.copy()
    for group in out.groups:
        moving = np.zeros(120, bool)
        moving[group] = True
        assert len(group) == 1 or not level.step_conflicts(before, moving)
        before[group] = desired[group]
    one_each = check.regroup([np.array([r]) for r in range(120)])  # a plan of single moves stays one at a time
    assert all(len(g) == 1 for g in one_each.groups)


def test_a_pair_keeps_the_higher_bound_of_its_robots():
    current, desired, position_var, heading_var = rough_change(40, 3)
    check = BodyCheck(CFG, current, desired, position_var, heading_var)
    moving = np.arange(40) % 2 == 0
    first = BodyCheck(CFG, current, desired, position_var, heading_var).step_conflicts(current, moving)
    levels = np.full(40, 1e-3)
    levels[[first[0].a, first[-1].b]] = [1e-2, 1e-1]  # two robots of conflicts at the strictest bound
    mixed = {(c.a, c.b): c.allowed for c in check.with_levels(levels).step_conflicts(current, moving)}
    by_level = {k: {(c.a, c.b): c.allowed for c in check.with_bound(k).step_conflicts(current, moving)} for k in (1e-3, 1e-2, 1e-1)}
    expected = {}
    for k, found in by_level.items():
        expected.update({pair: r for pair, r in found.items() if max(levels[pair[0]], levels[pair[1]]) == k})
    assert mixed == expected
    assert any(r > by_level[1e-3][pair] for pair, r in mixed.items() if pair in by_level[1e-3])  # the raised robots' pairs allow more
    assert check.with_levels(np.full(40, 1e-3)).levels is None  # equal bounds: the plain check
