"""Observability of the swarm from its observation graph (the connectivity of Section 5).

The paper's localization applies "as long as the post-motion swarm configuration
remains connected (i.e., each robot can be sensed by at least one neighbor)": every
robot must be observed by another robot, and the observation graph (edges taken in
both directions) must form one connected component. A run keeps to that rule
(``observable_subset``): the robots it leaves out keep their dead reckoning.

Measured data has no dead reckoning, and one-way sightings are common: a robot that
nobody saw is still fixed by what it saw. ``fixed_poses`` follows the observations in
both directions from one robot whose pose is the gauge (an observation i -> j gives the
offset of j in i's frame): a known pose of i puts j; a known position of i and of j fixes
i's heading; two robots of known position seen by i fix i's pose; a known heading of i
and position of j put i. Groups fixed from different gauges that share two robots, or one
robot whose heading both fix, are one rigid body (``rigid_groups``); ``localizable_subset``
keeps the largest. The rule is sufficient, not necessary: a group that only the whole system
of equations fixes (e.g. a triangle of one-way sightings, which has a mirror solution, or
groups linked by ranges alone) is left out.
"""

from __future__ import annotations

from typing import cast

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from runtime.errors import LocalizationError
from runtime.models.graph import component_labels


def unobserved(n: int, observed: np.ndarray) -> np.ndarray:
    """Indices of robots that no robot observed."""
    return np.flatnonzero(np.bincount(observed, minlength=n) == 0)


SMALL_GRAPH = 64  # robots up to which labels are propagated with numpy (building a scipy.sparse matrix costs more)


def components(n: int, observer: np.ndarray, observed: np.ndarray) -> np.ndarray:
    """Connected-component label per robot of the undirected observation graph.

    Labels are arbitrary integers (only equality matters), as ``connected_components`` gives.
    """
    if n <= SMALL_GRAPH:
        return component_labels(n, observer, observed)
    adj = sp.coo_matrix((np.ones(len(observer)), (observer, observed)), shape=(n, n))
    return cast(np.ndarray, connected_components(adj, directed=False)[1])


def _pairs(n: int, observer: np.ndarray, observed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distinct (observer, observed) pairs, self-observations left out."""
    pair = np.unique(observer * n + observed)
    i, j = pair // n, pair % n
    return i[i != j], j[i != j]


def _propagate(i: np.ndarray, j: np.ndarray, pos: np.ndarray, head: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rules of the module docstring from known positions ``pos`` and headings ``head``, until nothing changes."""
    n = len(pos)
    while True:
        p, h = pos.copy(), head.copy()
        p[j[pos[i] & head[i]]] = True  # a known pose puts what it sees
        p[i[head[i] & pos[j]]] = True  # a known heading and a known target put the observer
        h[i[pos[i] & pos[j]]] = True  # a known position seeing a known position: the heading
        two = np.bincount(i[pos[j]], minlength=n) >= 2  # two known targets: the whole pose
        p |= two
        h |= two
        if np.array_equal(p, pos) and np.array_equal(h, head):
            return pos, head
        pos, head = p, h


def fixed_poses(
    n: int, observer: np.ndarray, observed: np.ndarray, ref: int, headings: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """(position fixed (n,), heading fixed (n,)) relative to robot ``ref``, whose pose is the gauge.

    The propagation rules of the module docstring, repeated until nothing changes. ``headings``
    (n,): robots whose heading a prior fixes (then every robot that an observation links to a
    fixed position is fixed too). Observations of a robot by itself are ignored.
    """
    pos = np.zeros(n, bool)
    head = np.zeros(n, bool) if headings is None else np.asarray(headings, bool).copy()
    pos[ref] = head[ref] = True
    return _propagate(*_pairs(n, observer, observed), pos, head)


def rigid_groups(
    n: int, observer: np.ndarray, observed: np.ndarray, headings: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """(positions, headings): (groups, n) masks of the robots whose positions (headings) are fixed
    relative to each other, one row per rigid group.

    Each robot that observed someone is a gauge (``fixed_poses``; one whose pose another's group
    already fixes gives the same group and is skipped). Two groups that share two robots, or one
    robot whose heading both fix, are one rigid body: they are merged and propagated again,
    until no two groups can be merged.
    """
    i, j = _pairs(n, observer, observed)
    base = np.zeros(n, bool) if headings is None else np.asarray(headings, bool)
    groups, heads = [], []
    tried = np.zeros(n, bool)
    for ref in np.unique(i):
        if tried[ref]:
            continue
        pos, head = np.zeros(n, bool), base.copy()
        pos[ref] = head[ref] = True
        pos, head = _propagate(i, j, pos, head)
        tried |= pos & head
        groups.append(pos)
        heads.append(head)
    while len(groups) > 1:
        p, f = np.array(groups, np.float32), np.array([g & h for g, h in zip(groups, heads, strict=True)], np.float32)
        link = ((p @ p.T) >= 2) | ((f @ f.T) >= 1)
        a, b = np.nonzero(np.triu(link, 1))
        if not a.size:
            break
        labels = component_labels(len(groups), a, b)
        merged_groups, merged_heads = [], []
        for label in range(labels.max() + 1):
            members = np.flatnonzero(labels == label)
            pos, head = _propagate(i, j, np.any([groups[k] for k in members], axis=0), np.any([heads[k] for k in members], axis=0))
            merged_groups.append(pos)
            merged_heads.append(head)
        groups, heads = merged_groups, merged_heads
    return np.array(groups, bool).reshape(-1, n), np.array(heads, bool).reshape(-1, n)


def localizable_subset(
    ids: np.ndarray, observer: np.ndarray, observed: np.ndarray, *, headings_known: bool = False
) -> tuple[np.ndarray, dict[int, str]]:
    """Largest group of robots whose positions the observations fix (``rigid_groups``), and why each
    other robot was left out: ``unobserved`` (no observation either way), ``disconnected`` (not linked
    to the group) or ``undetermined`` (linked, but not fixed: e.g. seen only by robots whose heading
    nothing fixes). ``headings_known``: a prior fixes every heading (the joint localizer with a prior).
    Of groups of equal size, the one of the lowest-indexed gauge wins.
    """
    n = len(ids)
    touched = (np.bincount(observer, minlength=n) + np.bincount(observed, minlength=n)) > 0
    groups = rigid_groups(n, observer, observed, np.ones(n, bool) if headings_known else None)[0]
    keep = groups[int(np.argmax(groups.sum(axis=1)))] if len(groups) else np.zeros(n, bool)
    labels = components(n, observer, observed)
    main = labels[np.argmax(keep)] if keep.any() else -1
    excluded = {
        int(ids[k]): "unobserved" if not touched[k] else "disconnected" if labels[k] != main else "undetermined"
        for k in np.flatnonzero(~keep)
    }
    return keep, excluded


def require_observable(ids: np.ndarray, observer: np.ndarray, observed: np.ndarray, *, headings_known: bool = False) -> None:
    """Raise ``LocalizationError`` naming the robots that cannot be localized.

    ``observer``/``observed`` are indices into ``ids``. A robot nobody observed is localized
    only when its own observations fix it (``fixed_poses`` from the lowest-indexed observer, the
    topology's gauge; ``headings_known``: a prior fixes every heading); the others are reported
    first as unobserved; otherwise robots outside the largest connected component.
    """
    n = len(ids)
    missing = unobserved(n, observed)
    if missing.size and len(observer):
        groups, heads = rigid_groups(n, observer, observed, np.ones(n, bool) if headings_known else None)
        ref = int(observer.min())  # the topology's gauge: its group is the one fixing its pose
        gauge = groups[groups[:, ref] & heads[:, ref]]
        missing = missing[~gauge.any(axis=0)[missing]]
    if missing.size:
        raise LocalizationError("unobserved", ids[missing], "no robot observed them, and what they observed does not fix them")
    labels = components(n, observer, observed)
    counts = np.bincount(labels)
    if len(counts) > 1:
        outside = labels != np.argmax(counts)
        raise LocalizationError(
            "disconnected", ids[outside], f"the observation graph splits into {len(counts)} groups"
        )


def observable_subset(ids: np.ndarray, observer: np.ndarray, observed: np.ndarray) -> tuple[np.ndarray, dict[int, str]]:
    """Largest set of robots that can be localized, and why each other robot was left out.

    Repeatedly drops observations touching excluded robots, robots nobody observes,
    and robots outside the largest connected component, until nothing changes.
    Returns (mask over ``ids`` of kept robots, {excluded id: reason}).
    """
    n = len(ids)
    keep = np.ones(n, bool)
    excluded: dict[int, str] = {}
    while True:
        live = keep[observer] & keep[observed]
        o, d = observer[live], observed[live]
        seen = np.bincount(d, minlength=n) > 0
        newly = keep & ~seen
        for k in np.flatnonzero(newly):
            excluded[int(ids[k])] = "unobserved"
        keep &= seen
        if not keep.any():
            return keep, excluded
        labels = components(n, o, d)
        counts = np.bincount(labels[keep])
        main = np.argmax(counts)
        outside = keep & (labels != main)
        for k in np.flatnonzero(outside):
            excluded[int(ids[k])] = "disconnected"
        keep &= ~outside
        if not newly.any() and not outside.any():
            return keep, excluded
