"""The body regrouping's schedule (runtime/models/substeps.py, docs/bodies.md "Regrouping"): sub-steps as large as
the pairs' constraints allow, never a pair at too much risk in one, fewer sub-steps than the greedy split before it."""

import numpy as np
import pytest

from runtime.models.bodies import BodyCheck
from runtime.models.config import ModelConfig
from runtime.models.substeps import schedule

CFG = ModelConfig()
R = CFG.robot_radius_m


def pairs(*edges: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    return np.array([a for a, _ in edges], np.int64), np.array([b for _, b in edges], np.int64)


def test_needs_join_a_round_and_robots_kept_apart_split_it():
    # 0 needs 1, 1 needs 2 (a chain: together in one sub-step); 3 and 4 need each other (a cycle: together);
    # 5 needs 6 but may not move with it (6 first); 7 is kept apart from 0
    needs = pairs((0, 1), (1, 2), (3, 4), (4, 3), (5, 6))
    apart = pairs((5, 6), (7, 0))
    steps, unclear = schedule([np.arange(8)], 8, needs, apart, np.zeros(8, bool))
    assert unclear == []
    assert [s.tolist() for s in steps] == [[0, 1, 2, 3, 4, 6], [5, 7]]


def test_a_round_keeps_to_its_group_and_the_longest_chain_goes_first():
    # groups A = {0, 1, 2}, B = {3, 4}: 0 needs 3 (of B), 3 needs 1 (of A): A, B, A; 2 and 4 are free
    needs = pairs((0, 3), (3, 1))
    steps, unclear = schedule([np.array([0, 1, 2]), np.array([3, 4])], 5, needs, pairs(), np.zeros(5, bool))
    assert unclear == []
    assert [s.tolist() for s in steps] == [[1, 2], [3, 4], [0]]


def test_robots_that_cannot_move_clear_go_one_at_a_time_after_their_needs():
    # 0 and 1 need each other but are kept apart (no order clears them); 2 is blocked by a robot that never moves;
    # 0 needs 3 (moved first), 4 needs 0 (after the pair)
    needs = pairs((0, 1), (1, 0), (0, 3), (4, 0))
    blocked = np.zeros(6, bool)
    blocked[2] = True
    steps, unclear = schedule([np.arange(5)], 6, needs, pairs((0, 1)), blocked)
    assert unclear == [0, 1, 2]
    assert [s.tolist() for s in steps] == [[3], [2], [0], [1], [4]]


def rough_check(n: int, seed: int) -> tuple[BodyCheck, np.ndarray]:
    """A crowded change of ``n`` robots with correlated covariances: the swarm shifted 0.3 m (robots follow each
    other: chains of needs) plus a reshape, pairs nearly touching at the start and the end, a head-on swap, robots
    that stay; each robot's pose covariance correlated in x, y and heading, and cross-covariances between
    neighbours in the joint covariance."""
    rng = np.random.default_rng(seed)
    side = int(np.ceil(np.sqrt(n)))
    grid = np.stack(np.meshgrid(np.arange(side), np.arange(side)), -1).reshape(-1, 2)[:n] * 0.12
    current = grid + rng.uniform(-0.02, 0.02, (n, 2))
    angle = rng.uniform(-np.pi, np.pi)
    desired = current + 0.3 * np.array([np.cos(angle), np.sin(angle)]) + rng.normal(0.0, 0.02, (n, 2))
    for a in range(0, 24, 6):  # nearly touching (2R + 0.5 mm) at the start and where they arrive
        turn = rng.uniform(-np.pi, np.pi)
        current[a + 1] = current[a] + (2 * R + 5e-4) * np.array([np.cos(turn), np.sin(turn)])
        desired[a + 3] = desired[a + 2] + (2 * R + 5e-4) * np.array([np.cos(turn), np.sin(turn)])
    still = rng.choice(np.arange(30, n), 2, replace=False)
    desired[still] = current[still]
    desired[40], desired[41] = current[41].copy(), current[40].copy()  # a swap
    mix = rng.normal(0.0, 1.0, (3 * n, 3 * n)) * 0.0005
    near = np.linalg.norm(current[:, None] - current[None], axis=-1) < 0.2  # cross terms between neighbours only
    mix *= np.kron(near, np.ones((3, 3)))
    mix[np.arange(3 * n), np.arange(3 * n)] = rng.uniform(0.001, 0.003, 3 * n) * np.tile([1.0, 1.0, 4.0], n)
    joint = mix @ mix.T
    cov = np.stack([joint[3 * k:3 * k + 3, 3 * k:3 * k + 3] for k in range(n)])
    return BodyCheck(CFG, current, desired, cov=cov, joint=joint), rng.permutation(n)


# sub-steps of the greedy split that regrouped these plans before (main at bf876ab)
BEFORE = {(0, 1): 38, (0, 2): 62, (1, 3): 64}


@pytest.mark.parametrize(("seed", "parts"), [(0, 1), (0, 2), (1, 3)])
def test_the_regrouping_never_moves_a_pair_at_risk_together_and_takes_fewer_substeps(seed, parts):
    check, order = rough_check(150, seed)
    groups = np.array_split(order, parts)
    out = check.regroup(groups)
    level = check.with_bound(out.bound) if out.levels is None else check.with_levels(out.levels)
    assert sorted(np.concatenate(out.groups).tolist()) == list(range(150))
    part = np.zeros(150, np.int64)
    for k, g in enumerate(groups):
        part[g] = k
    before = check.current.copy()
    for step in out.groups:
        moving = np.zeros(150, bool)
        moving[step] = True
        if len(step) > 1 or step[0] not in out.unclear:
            assert level.step_conflicts(before, moving) == []
            assert len(set(part[step].tolist())) == 1  # a sub-step keeps to one group of the plan
        before[step] = check.desired[step]
    assert len(out.groups) <= BEFORE[(seed, parts)]
