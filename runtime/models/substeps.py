"""Sub-steps of a plan under pairwise constraints: the schedule behind the body regrouping (``docs/bodies.md``).

Whether a step keeps the chance constraint is decided pair by pair (``runtime.models.bodies``): a mover against a
robot standing where it started, against one standing where it arrived, or against one moving with it. So a split
of a plan into sub-steps is a schedule of the robots' single moves under three relations:

* ``needs`` (a, b): a's move may not pass b standing where it started: b moves before a or with it;
* the same from a's move that may not pass b standing where b arrives: a moves before b or with it (``needs`` (b, a));
* ``apart`` (a, b): a and b may not move in the same sub-step.

Robots that need each other in a cycle (a strongly connected component of ``needs``, e.g. two robots whose paths
each pass where the other starts) move together; the components then go in an order of the acyclic graph of
``needs`` between them, in rounds: a round belongs to one of the plan's groups (a sub-step never mixes robots of two
groups, except a component that does) and takes every component of that group whose needs have moved or move in
this round and that is not ``apart`` from one taken, so a sub-step is as large as the relations allow, not a
prefix of the plan's order. The next round goes to the group of the waiting component with the longest chain of
rounds still to follow it (a critical path: a step of needs into another group or between robots kept apart
adds a round), ties in the plan's order. A component that cannot move clear (two of its robots kept apart, or a
robot ``blocked`` by one that never moves) moves one robot at a time when its needs have moved, and is
returned as unclear.
"""

from __future__ import annotations

import heapq

import numpy as np


def schedule(groups: list[np.ndarray], n: int, needs: tuple[np.ndarray, np.ndarray], apart: tuple[np.ndarray, np.ndarray],
             blocked: np.ndarray) -> tuple[list[np.ndarray], list[int]]:
    """Sub-steps moving every robot of ``groups`` (robot indices < ``n``, in the plan's order) once, and the unclear
    robots, sorted (module docstring). ``needs`` and ``apart``: pairs (a, b) of the groups' robots as two index
    arrays; ``blocked`` (n,): robots that no order clears."""
    from scipy.sparse import coo_matrix  # noqa: PLC0415 - scipy only when a plan needs regrouping
    from scipy.sparse.csgraph import connected_components  # noqa: PLC0415

    every = np.concatenate([np.asarray(g, np.int64) for g in groups]) if groups else np.zeros(0, np.int64)
    if not len(every):
        return [], []
    part = np.full(n, -1, np.int64)
    part[every] = np.repeat(np.arange(len(groups)), [len(g) for g in groups])
    position = np.full(n, -1, np.int64)
    position[every] = np.arange(len(every))
    need_a, need_b = (np.asarray(x, np.int64) for x in needs)
    apart_a, apart_b = (np.asarray(x, np.int64) for x in apart)
    graph = coo_matrix((np.ones(len(need_a)), (need_a, need_b)), shape=(n, n)).tocsr()
    _, label = connected_components(graph, directed=True, connection="strong")
    comps, comp = np.unique(label[every], return_inverse=True)  # components of the plan's robots, 0..k-1
    k = len(comps)
    of = np.full(n, -1, np.int64)
    of[every] = comp
    by_comp = np.lexsort((position[every], comp))  # members of each component in the plan's order
    members = np.split(every[by_comp], np.flatnonzero(np.diff(comp[by_comp])) + 1)
    first = np.array([position[m[0]] for m in members], np.int64)
    home = np.array([part[m].min() for m in members], np.int64)
    ca, cb = of[apart_a], of[apart_b]
    infeasible = np.zeros(k, bool)
    infeasible[ca[ca == cb]] = True
    infeasible[of[every[np.asarray(blocked, bool)[every]]]] = True
    split = ca != cb
    kept = {(int(a), int(b)) for a, b in zip(ca[split].tolist(), cb[split].tolist(), strict=True)}
    kept |= {(b, a) for a, b in kept}
    away: list[list[int]] = [[] for _ in range(k)]
    for a, b in kept:
        away[a].append(b)
    ea, eb = of[need_b], of[need_a]  # component ea enables eb (eb needs ea)
    cross = ea != eb
    edges = np.unique(np.column_stack([ea[cross], eb[cross]]), axis=0) if cross.any() else np.zeros((0, 2), np.int64)
    enables: list[list[int]] = [[] for _ in range(k)]
    waiting = np.zeros(k, np.int64)
    for a, b in edges.tolist():
        enables[a].append(b)
        waiting[b] += 1
    height = _rounds_after(k, enables, waiting, home, kept)
    heaps: dict[int, list[tuple[int, int, int]]] = {}
    lead: list[tuple[int, int, int]] = []  # every ready component, for the next round's group

    def ready(c: int) -> None:
        key = (-int(height[c]), int(first[c]), c)
        heapq.heappush(heaps.setdefault(int(home[c]), []), key)
        heapq.heappush(lead, key)

    for c in np.flatnonzero(waiting == 0).tolist():
        ready(c)
    done = np.zeros(k, bool)
    in_round = np.zeros(k, bool)
    out: list[np.ndarray] = []
    unclear: list[int] = []

    def moved(c: int) -> None:
        done[c] = True
        for b in enables[c]:
            waiting[b] -= 1
            if not waiting[b]:
                ready(b)

    while lead:
        c = heapq.heappop(lead)[2]
        if done[c]:
            continue
        heap = heaps[int(home[c])]  # its group's round: it is the first taken
        taken, later, alone = [], [], []
        while heap:
            key = heapq.heappop(heap)
            c = key[2]
            if infeasible[c]:
                alone.append(c)
            elif any(in_round[d] for d in away[c]):
                later.append(key)
            else:
                in_round[c] = True
                taken.append(c)
                for b in enables[c]:  # a component needing only robots of this round may join it
                    waiting[b] -= 1
                    if not waiting[b]:
                        ready(b)
        if taken:
            rows = np.concatenate([members[c] for c in taken])
            out.append(rows[np.argsort(position[rows], kind="stable")])
            for c in taken:
                done[c] = True
                in_round[c] = False
        for c in alone:  # its needs have moved: its robots one at a time, every other robot standing
            out += [np.array([r]) for r in members[c]]
            unclear += members[c].tolist()
            moved(c)
        for key in later:
            heapq.heappush(heap, key)
            heapq.heappush(lead, key)
    return out, sorted(unclear)


def _rounds_after(k: int, enables: list[list[int]], waiting: np.ndarray, home: np.ndarray, kept: set[tuple[int, int]]) -> np.ndarray:
    """(k,) for each component the longest chain of rounds that must follow its own: along ``enables``, a
    component of another group or one kept apart from it needs a later round."""
    count = waiting.copy()
    order = []
    stack = np.flatnonzero(count == 0).tolist()
    while stack:  # a topological order (Kahn)
        c = stack.pop()
        order.append(c)
        for b in enables[c]:
            count[b] -= 1
            if not count[b]:
                stack.append(b)
    height = np.zeros(k, np.int64)
    for c in reversed(order):
        for b in enables[c]:
            later = int(home[b] != home[c] or (c, b) in kept)
            height[c] = max(height[c], height[b] + later)
    return height
