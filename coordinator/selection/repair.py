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
than ``MAX_CONFLICTS`` conflicting pairs: a few swaps cannot clear it).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from coordinator.plan import Plan
from coordinator.selection.heuristic import step_score
from runtime.models.bodies import BodyCheck

PARTNERS = 8  # nearest robots (by desired position) in other groups tried for each robot of a conflict
MAX_ROUNDS = 8  # swaps at most
MAX_CONFLICTS = 3 * MAX_ROUNDS  # more conflicting pairs than this: not tried (n_r = 10: 4-17; n_r = 30, 100: 10-200, never repaired)


def conflicts(plan: Plan, bodies: BodyCheck) -> tuple[int, set[int]]:
    """(conflicting pairs over all steps, the robots in them) of ``plan``'s nominal motion."""
    before = bodies.current.copy()
    count, robots = 0, set[int]()
    for group in plan.groups:
        found = bodies.step_conflicts(before, _mask(group, len(before)))
        count += len(found)
        robots.update(r for c in found for r in (c.a, c.b))
        before[group] = bodies.desired[group]
    return count, robots


def step_counts(plan: Plan, bodies: BodyCheck, first: int = 0, last: int | None = None, limit: int | None = None) -> list[int]:
    """Conflicting pairs of steps ``first`` to ``last`` (inclusive; default: to the end), stopping once ``limit`` are found."""
    groups = plan.groups
    before = bodies.current.copy()
    for group in groups[:first]:
        before[group] = bodies.desired[group]
    out: list[int] = []
    for group in groups[first: len(groups) if last is None else last + 1]:
        if limit is not None and sum(out) >= limit:
            break
        out.append(len(bodies.step_conflicts(before, _mask(group, len(before)))))
        before[group] = bodies.desired[group]
    return out


def _mask(group: np.ndarray, n: int) -> np.ndarray:
    moving = np.zeros(n, bool)
    moving[group] = True
    return moving


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


def repair(plan: Plan, bodies: BodyCheck, connected: Callable[[Plan], bool]) -> Plan | None:
    """``plan`` if it is clear and connected, else a clear connected plan a few swaps away, or None."""
    if not connected(plan):
        return None
    count, robots = conflicts(plan, bodies)
    if count == 0:
        return plan
    if count > MAX_CONFLICTS:
        return None
    group_of = np.empty(plan.n_robots, np.int64)
    group_of[plan.order] = np.repeat(np.arange(plan.n_steps), plan.sizes)
    gap = np.linalg.norm(bodies.desired[:, None] - bodies.desired[None], axis=-1)
    for _ in range(MAX_ROUNDS):
        per_step = step_counts(plan, bodies)  # a swap of groups a < b changes steps a..b only
        tried: set[tuple[int, int]] = set()
        best: tuple[int, float, Plan] | None = None
        for i in sorted(robots):
            others = np.flatnonzero(group_of != group_of[i])
            for j in others[np.argsort(gap[i, others], kind="stable")[:PARTNERS]]:
                pair = (min(i, int(j)), max(i, int(j)))
                if pair in tried:
                    continue
                tried.add(pair)
                a, b = sorted((int(group_of[pair[0]]), int(group_of[pair[1]])))
                outside = count - sum(per_step[a: b + 1])
                limit = count if best is None else best[0] + 1
                candidate = swapped(plan, *pair)
                left = outside + sum(step_counts(candidate, bodies, a, b, limit - outside))
                if left >= count or (best is not None and left > best[0]) or not connected(candidate):
                    continue
                value = heuristic_value(candidate, bodies.current, bodies.desired)
                if best is None or (left, -value) < (best[0], -best[1]):
                    best = (left, value, candidate)
        if best is None:
            return None
        count, plan = best[0], best[2]
        group_of[plan.order] = np.repeat(np.arange(plan.n_steps), plan.sizes)
        if count == 0:
            return plan
        robots = conflicts(plan, bodies)[1]
    return None
