"""A heuristic plan made clear for bodies (constraint g of Eq. 4) by a few single swaps.

With bodies (``docs/bodies.md``) the heuristic plan of Eq. 11-13 often has a step whose nominal
motion brings two robots too close: a mover crossing an anchor or another mover. The plan is
then infeasible and, before this repair, its count went to the genetic search from random
permutations just to find a feasible plan. ``repair`` instead descends on the number of
conflicting pairs by single swaps (two robots of different groups exchanged), each round
trying only the swaps that move a robot of a conflicting pair with one of its
``PARTNERS`` nearest robots (by desired position) in another group, and taking the swap with
the fewest conflicts left (ties: the highest heuristic value, Eq. 13 summed over the steps,
so the plan stays as close to the heuristic's choice as the bodies allow). It stops at a clear,
connected plan, or returns None when a round removes no conflict (or, at once, when the plan has more
than ``MAX_CONFLICTS`` conflicting pairs: a few swaps cannot clear it). Conflicts are counted from the
pair verdicts of ``clear_pairs.PairTable``, the same as ``BodyCheck.step_conflicts`` step by step.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from coordinator.plan import Plan
from coordinator.selection.clear_pairs import PairTable, plan_steps
from coordinator.selection.heuristic import step_score

PARTNERS = 8  # nearest robots (by desired position) in other groups tried for each robot of a conflict
MAX_ROUNDS = 8  # swaps at most
MAX_CONFLICTS = 3 * MAX_ROUNDS  # more conflicting pairs than this: not tried (n_r = 10: 4-17; n_r = 30, 100: 10-200, never repaired)


def conflicts(plan: Plan, pairs: PairTable) -> tuple[int, set[int]]:
    """(conflicting pairs over all steps, the robots in them) of ``plan``'s nominal motion."""
    found = pairs.conflicting(plan)
    return len(found), set(found.ravel().tolist())


def heuristic_value(plan: Plan, current: np.ndarray, desired: np.ndarray) -> float:
    """Sum over the steps of p_ak (Eq. 13) in the expected post-step configurations."""
    base = np.array(current, dtype=float)
    total = 0.0
    for group in plan.groups[:-1]:  # the last step has no anchors left to choose
        mask = np.zeros((1, len(base)), bool)
        mask[0, group] = True
        total += float(step_score(mask, base, desired)[0])
        base[group] = desired[group]
    return total


def swapped(plan: Plan, i: int, j: int) -> Plan:
    """``plan`` with robots ``i`` and ``j`` exchanged."""
    order = plan.order.copy()
    a, b = np.flatnonzero(order == i)[0], np.flatnonzero(order == j)[0]
    order[a], order[b] = order[b], order[a]
    return Plan(order, plan.sizes)


def repair(plan: Plan, pairs: PairTable, connected: Callable[[Plan], bool]) -> Plan | None:
    """``plan`` if it is clear and connected, else a clear connected plan a few swaps away, or None."""
    if not connected(plan):
        return None
    count, robots = conflicts(plan, pairs)
    if count == 0:
        return plan
    if count > MAX_CONFLICTS:
        return None
    group_of = plan_steps(plan)
    gap = np.linalg.norm(pairs.desired[:, None] - pairs.desired[None], axis=-1)
    for _ in range(MAX_ROUNDS):
        tried: set[tuple[int, int]] = set()
        best: tuple[int, float, Plan] | None = None
        for i in sorted(robots):
            others = np.flatnonzero(group_of != group_of[i])
            for j in others[np.argsort(gap[i, others], kind="stable")[:PARTNERS]]:
                pair = (min(i, int(j)), max(i, int(j)))
                if pair in tried:
                    continue
                tried.add(pair)
                candidate = swapped(plan, *pair)
                left = len(pairs.conflicting(candidate))
                if left >= count or (best is not None and left > best[0]) or not connected(candidate):
                    continue
                value = heuristic_value(candidate, pairs.current, pairs.desired)
                if best is None or (left, -value) < (best[0], -best[1]):
                    best = (left, value, candidate)
        if best is None:
            return None
        count, plan = best[0], best[2]
        group_of = plan_steps(plan)
        if count == 0:
            return plan
        robots = conflicts(plan, pairs)[1]
    return None
