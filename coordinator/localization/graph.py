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
and position of j put i. ``localizable_subset`` keeps the largest group it fixes.
The rule is sufficient, not necessary: a group that only the whole system of equations
fixes (e.g. a triangle of one-way sightings, which has a mirror solution) is left out.
"""

from __future__ import annotations

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
    return connected_components(adj, directed=False)[1]


def fixed_poses(
    n: int, observer: np.ndarray, observed: np.ndarray, ref: int, headings: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """(position fixed (n,), heading fixed (n,)) relative to robot ``ref``, whose pose is the gauge.

    The propagation rules of the module docstring, repeated until nothing changes. ``headings``
    (n,): robots whose heading a prior fixes (then every robot that an observation links to a
    fixed position is fixed too). Observations of a robot by itself are ignored.
    """
    pair = np.unique(observer * n + observed)
    i, j = pair // n, pair % n
    i, j = i[i != j], j[i != j]
    pos = np.zeros(n, bool)
    head = np.zeros(n, bool) if headings is None else np.asarray(headings, bool).copy()
    pos[ref] = head[ref] = True
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


def localizable_subset(
    ids: np.ndarray, observer: np.ndarray, observed: np.ndarray, *, headings_known: bool = False
) -> tuple[np.ndarray, dict[int, str]]:
    """Largest group of robots whose positions the observations fix (``fixed_poses``), and why each
    other robot was left out: ``unobserved`` (no observation either way), ``disconnected`` (not linked
    to the group) or ``undetermined`` (linked, but not fixed: e.g. seen only by robots whose heading
    nothing fixes). ``headings_known``: a prior fixes every heading (the joint localizer with a prior).

    Every robot that observed someone is tried as the gauge; the first with the largest group wins.
    """
    n = len(ids)
    touched = (np.bincount(observer, minlength=n) + np.bincount(observed, minlength=n)) > 0
    headings = np.ones(n, bool) if headings_known else None
    keep = np.zeros(n, bool)
    tried = np.zeros(n, bool)
    for ref in np.unique(observer):
        if tried[ref]:
            continue
        pos, head = fixed_poses(n, observer, observed, int(ref), headings)
        tried |= pos & head  # any of them as the gauge fixes the same group
        if pos.sum() > keep.sum():
            keep = pos
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
        headings = np.ones(n, bool) if headings_known else None
        missing = missing[~fixed_poses(n, observer, observed, int(observer.min()), headings)[0][missing]]
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
