"""Known answers for the observability of the observation graph (coordinator/localization/graph.py).

Connected components are compared with a breadth-first search written in the test; the subset and
error cases are small graphs worked out by hand in the docstrings.
"""

from __future__ import annotations

import numpy as np
import pytest

from coordinator.localization.graph import (
    SMALL_GRAPH,
    components,
    fixed_poses,
    localizable_subset,
    observable_subset,
    require_observable,
    rigid_groups,
    unobserved,
)
from runtime.errors import LocalizationError


def reference_partition(n: int, observer: np.ndarray, observed: np.ndarray) -> set[frozenset[int]]:
    """Components of the undirected graph by breadth-first search."""
    nbrs: list[set[int]] = [set() for _ in range(n)]
    for a, b in zip(observer.tolist(), observed.tolist(), strict=True):
        nbrs[a].add(b)
        nbrs[b].add(a)
    seen, parts = set(), set()
    for s in range(n):
        if s in seen:
            continue
        comp, todo = {s}, [s]
        while todo:
            for m in nbrs[todo.pop()] - comp:
                comp.add(m)
                todo.append(m)
        seen |= comp
        parts.add(frozenset(comp))
    return parts


def partition(labels: np.ndarray) -> set[frozenset[int]]:
    return {frozenset(np.flatnonzero(labels == v).tolist()) for v in np.unique(labels)}


@pytest.mark.parametrize("n", [1, 7, SMALL_GRAPH, SMALL_GRAPH + 1, 150])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_components_match_breadth_first_search(n, seed):
    """Random directed edges (about one per robot, so several components, long chains and isolated
    robots); the labels' partition equals the BFS components, on both sides of the 64-robot switch."""
    rng = np.random.default_rng(seed)
    m = n
    observer, observed = rng.integers(0, n, m), rng.integers(0, n, m)
    labels = components(n, observer, observed)
    assert labels.shape == (n,)
    assert partition(labels) == reference_partition(n, observer, observed)


def test_a_long_chain_is_one_component():
    """A path 0 - 1 - ... - 39 given in reverse direction needs 39 label-propagation rounds."""
    n = 40
    labels = components(n, np.arange(1, n), np.arange(n - 1))
    assert len(set(labels.tolist())) == 1


def test_unobserved_by_hand():
    """Robots 0..4, observed robots 1, 1, 3: robots 0, 2 and 4 were seen by nobody."""
    assert unobserved(5, np.array([1, 1, 3])).tolist() == [0, 2, 4]
    assert unobserved(3, np.array([], int)).tolist() == [0, 1, 2]


def test_require_observable_names_the_robots():
    """ids 10..14. Observations 0->1, 1->0, 2->0, 3->4, 4->3: robot 2 (id 12) unobserved. Adding 0->2 makes
    everyone observed but {0, 1, 2} and {3, 4} are two groups: ids 13 and 14 lie outside the largest."""
    ids = np.arange(10, 15)
    obs, seen = np.array([0, 1, 2, 3, 4]), np.array([1, 0, 0, 4, 3])
    message = r"^unobserved: robots \[12\] \(no robot observed them, and what they observed does not fix them\)$"
    with pytest.raises(LocalizationError, match=message) as err:
        require_observable(ids, obs, seen)
    assert (err.value.reason, err.value.robots) == ("unobserved", [12])
    obs, seen = np.append(obs, 0), np.append(seen, 2)
    with pytest.raises(LocalizationError, match="splits into 2 groups") as err:
        require_observable(ids, obs, seen)
    assert (err.value.reason, err.value.robots) == ("disconnected", [13, 14])
    require_observable(ids, np.append(obs, 2), np.append(seen, 3))  # 2 -> 3 joins the groups


def test_observable_subset_cascades():
    """ids 10..14; observations 0<->1, 1<->2, 3->2, 3->4. Round 1: robot 3 is unobserved and dropped
    (the graph is still connected through its edges). Round 2: without robot 3's observations robot 4
    is unobserved too. Round 3 changes nothing: robots 0, 1, 2 remain."""
    ids = np.arange(10, 15)
    obs, seen = np.array([0, 1, 1, 2, 3, 3]), np.array([1, 0, 2, 1, 2, 4])
    keep, why = observable_subset(ids, obs, seen)
    assert keep.dtype == bool and keep.tolist() == [True, True, True, False, False]
    assert why == {13: "unobserved", 14: "unobserved"}


def test_observable_subset_keeps_the_largest_group():
    """ids 10..15; observations 0<->1, 0<->5, 2<->3, 4->2: everyone is observed but robot 4; it is
    dropped, then {0, 1, 5} (3 robots) beats {2, 3} (2 robots), whose members are 'disconnected'."""
    ids = np.arange(10, 16)
    obs, seen = np.array([0, 1, 0, 5, 2, 3, 4]), np.array([1, 0, 5, 0, 3, 2, 2])
    keep, why = observable_subset(ids, obs, seen)
    assert keep.tolist() == [True, True, False, False, False, True]
    assert why == {14: "unobserved", 12: "disconnected", 13: "disconnected"}
    assert all(type(k) is int for k in why)


def test_observable_subset_of_nobody_observed():
    """No observations: every robot is unobserved, nothing is kept."""
    keep, why = observable_subset(np.array([7, 8]), np.array([], int), np.array([], int))
    assert keep.tolist() == [False, False] and why == {7: "unobserved", 8: "unobserved"}


def test_observable_subset_keeps_a_connected_swarm():
    """A ring 0 -> 1 -> 2 -> 0: everyone kept, nothing excluded."""
    keep, why = observable_subset(np.array([1, 2, 3]), np.array([0, 1, 2]), np.array([1, 2, 0]))
    assert keep.tolist() == [True, True, True] and why == {}


def test_the_largest_group_need_not_contain_robot_0():
    """ids 10..14; observations 0<->1 and 2<->3<->4: the larger group {2, 3, 4} is kept (or, when
    requiring everyone, ids 10 and 11 are named as outside it)."""
    ids = np.arange(10, 15)
    obs, seen = np.array([0, 1, 2, 3, 3, 4]), np.array([1, 0, 3, 2, 4, 3])
    with pytest.raises(LocalizationError, match="splits into 2 groups") as err:
        require_observable(ids, obs, seen)
    assert (err.value.reason, err.value.robots) == ("disconnected", [10, 11])
    keep, why = observable_subset(ids, obs, seen)
    assert keep.tolist() == [False, False, True, True, True]
    assert why == {10: "disconnected", 11: "disconnected"}


def test_component_labels_are_numbered_by_lowest_node():
    """Edges 3-1, 1-0, 5-4 on 7 nodes: components {0, 1, 3}, {2}, {4, 5}, {6}, numbered by their lowest
    node (0, 2, 4, 6 -> 0, 1, 2, 3): labels [0, 0, 1, 0, 2, 2, 3]. A path 6-5-4-3-2-1-0 given in reverse
    (the worst case for plain minimum propagation) is one component."""
    from runtime.models.graph import component_labels

    np.testing.assert_array_equal(component_labels(7, np.array([3, 1, 5]), np.array([1, 0, 4])), [0, 0, 1, 0, 2, 2, 3])
    np.testing.assert_array_equal(component_labels(7, np.arange(6, 0, -1), np.arange(5, -1, -1)), np.zeros(7))
    assert component_labels(0, np.zeros(0, int), np.zeros(0, int)).shape == (0,)


def test_fixed_poses_follow_one_way_sightings():
    """Robot 2 sees 0 and 1, nobody sees 2: from 2 (the gauge) both positions are fixed, their headings not.
    From 0 (it sees nobody, no gauge heading): only 0 itself."""
    pos, head = fixed_poses(3, np.array([2, 2]), np.array([0, 1]), 2)
    assert pos.tolist() == [True, True, True] and head.tolist() == [False, False, True]


def test_fixed_poses_by_hand():
    """0 -> 1 -> 2: 1 is put by 0's pose, but 1's heading is free (it sees only 2, whose position is not
    fixed), so 2 can be anywhere on a circle around 1. Adding 2 -> 0 and 2 -> 1 (two fixed targets) fixes
    2's pose, then 1's heading. With every heading known from a prior, 0 -> 1 -> 2 already fixes all."""
    i, j = np.array([0, 1]), np.array([1, 2])
    pos, head = fixed_poses(3, i, j, 0)
    assert pos.tolist() == [True, True, False] and head.tolist() == [True, False, False]
    pos, head = fixed_poses(3, np.append(i, [2, 2]), np.append(j, [0, 1]), 0)
    assert pos.all() and head.all()
    assert fixed_poses(3, i, j, 0, np.ones(3, bool))[0].all()


def test_localizable_subset_keeps_a_silent_sensor_and_what_depends_on_it():
    """ids 10..14. 0 <-> 1, 0 -> 2, 1 -> 2, 3 <-> 0, 4 -> 0, 4 -> 1: robot 2's sensor is silent (it observed
    nobody) and 4 was seen by nobody. A run's rule drops 4; measured data keeps everyone (4 saw two robots
    of fixed position)."""
    ids = np.arange(10, 15)
    obs, seen = np.array([0, 1, 0, 1, 3, 0, 4, 4]), np.array([1, 0, 2, 2, 0, 3, 0, 1])
    assert observable_subset(ids, obs, seen)[1] == {14: "unobserved"}
    keep, why = localizable_subset(ids, obs, seen)
    assert keep.all() and why == {}
    require_observable(ids, obs, seen)  # 4 is fixed by what it saw


def test_localizable_subset_names_why():
    """ids 10..17. 0 <-> 1, 1 -> 2 (2 seen by exactly one robot, whose pose is fixed: kept), 2 -> 3 (2's
    heading is free: 3 undetermined), 4 alone (unobserved), 5 <-> 6 (a second, smaller group: disconnected),
    7 -> 0 (seen by nobody, sees one robot: undetermined; a prior's heading would fix it)."""
    ids = np.arange(10, 18)
    obs, seen = np.array([0, 1, 1, 2, 5, 6, 7]), np.array([1, 0, 2, 3, 6, 5, 0])
    keep, why = localizable_subset(ids, obs, seen)
    assert keep.tolist() == [True, True, True, False, False, False, False, False]
    assert why == {13: "undetermined", 14: "unobserved", 15: "disconnected", 16: "disconnected", 17: "undetermined"}
    keep, why = localizable_subset(ids, obs, seen, headings_known=True)
    assert keep.tolist() == [True, True, True, True, False, False, False, True]


def test_a_triangle_of_one_way_sightings_is_left_partly_out():
    """0 -> 1 -> 2 -> 0 has a mirror solution (2 on either side of the line 0-1): the rule is sufficient,
    not necessary, and keeps the first pair only."""
    keep, why = localizable_subset(np.arange(3), np.array([0, 1, 2]), np.array([1, 2, 0]))
    assert keep.tolist() == [True, True, False] and why == {2: "undetermined"}


def test_groups_sharing_two_robots_are_one_rigid_body():
    """0 <-> 1 see the silent robots 4 and 5 (0 -> 4, 1 -> 5); so do 2 <-> 3 (2 -> 4, 3 -> 5). From gauge 0
    only {0, 1, 4, 5} is fixed, from 2 only {2, 3, 4, 5}; sharing two robots, they are one rigid body."""
    obs, seen = np.array([0, 1, 0, 1, 2, 3, 2, 3]), np.array([1, 0, 4, 5, 3, 2, 4, 5])
    assert fixed_poses(6, obs, seen, 0)[0].tolist() == [True, True, False, False, True, True]
    groups, heads = rigid_groups(6, obs, seen)
    assert groups.tolist() == [[True] * 6] and heads.tolist() == [[True, True, True, True, False, False]]
    keep, why = localizable_subset(np.arange(6), obs, seen)
    assert keep.all() and why == {}
    groups, _ = rigid_groups(6, obs[:-1], seen[:-1])  # without 3 -> 5 they share only robot 4
    assert sorted(map(tuple, groups.tolist())) == [(False, False, True, True, True, False), (True, True, False, False, True, True)]
    assert localizable_subset(np.arange(6), obs[:-1], seen[:-1])[0].tolist() == [True, True, False, False, True, True]


def fixed_by_rank(n: int, i: np.ndarray, j: np.ndarray, poses: np.ndarray, ref: int) -> np.ndarray:
    """Robots whose position the topology's equations fix locally relative to ``ref``'s pose: zero rows of
    the null space of the Jacobian of R(theta_i) z_ij + x_i - x_j at ``poses`` (headings of observers only)."""
    observer = np.bincount(i, minlength=n) > 0
    col = np.full((n, 3), -1)
    free = np.stack([np.arange(n) != ref] * 2 + [(np.arange(n) != ref) & observer], axis=1)
    col[free] = np.arange(free.sum())
    jac = np.zeros((len(i), 2, free.sum() + 1))  # the last column takes the gauge's (dropped) entries
    m = np.arange(len(i))
    d = poses[j, :2] - poses[i, :2]
    for ax in range(2):
        jac[m, ax, col[i, ax]] += 1.0
        jac[m, ax, col[j, ax]] -= 1.0
    jac[m, 0, col[i, 2]] = -d[:, 1]
    jac[m, 1, col[i, 2]] = d[:, 0]
    jac = jac.reshape(2 * len(i), -1)[:, :-1]
    _, sv, vt = np.linalg.svd(jac)
    null = vt[int((sv > 1e-9 * sv.max()).sum()):]
    out = np.ones(n, bool)
    for k in np.flatnonzero(np.arange(n) != ref):
        out[k] = np.abs(null[:, col[k, :2]]).max(initial=0.0) < 1e-7
    return out


def test_what_the_rule_keeps_the_equations_fix():
    """Random 10-robot graphs of one-way sightings: every robot ``localizable_subset`` keeps is fixed by the
    equations (the rank of the Jacobian, from a gauge of its group), and it keeps nearly all the rank finds
    (the rest: mirror solutions, groups linked by ranges alone). The run's rule keeps some that are not fixed."""
    rng = np.random.default_rng(0)
    kept = fixed = loose_runs = 0
    for _ in range(40):
        n = 10
        poses = np.column_stack([rng.uniform(0, 1, (n, 2)), rng.uniform(-np.pi, np.pi, n)])
        i, j = np.nonzero((rng.random((n, n)) < rng.uniform(0.15, 0.5)) & ~np.eye(n, dtype=bool))
        keep, _ = localizable_subset(np.arange(n), i, j)
        if not keep.any():
            continue
        groups, heads = rigid_groups(n, i, j)
        group = int(np.argmax(groups.sum(axis=1)))
        rank = fixed_by_rank(n, i, j, poses, int(np.flatnonzero(groups[group] & heads[group])[0]))
        assert not (keep & ~rank).any()
        kept, fixed = kept + keep.sum(), fixed + rank.sum()
        old, _ = observable_subset(np.arange(n), i, j)
        inside = old[i] & old[j]
        if old.any():
            loose_runs += (old & ~fixed_by_rank(n, i[inside], j[inside], poses, int(i[inside].min()))).sum()
    assert 0.95 * fixed <= kept <= fixed and loose_runs > 0
