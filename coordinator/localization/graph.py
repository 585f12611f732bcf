"""Observability of the swarm from its observation graph (the connectivity of Section 5).

The paper's localization applies "as long as the post-motion swarm configuration
remains connected (i.e., each robot can be sensed by at least one neighbor)": every
robot must be observed by another robot, and the observation graph (edges taken in
both directions) must form one connected component.
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


def require_observable(ids: np.ndarray, observer: np.ndarray, observed: np.ndarray) -> None:
    """Raise ``LocalizationError`` naming the robots that cannot be localized.

    ``observer``/``observed`` are indices into ``ids``. Unobserved robots are reported
    first; otherwise robots outside the largest connected component.
    """
    n = len(ids)
    missing = unobserved(n, observed)
    if missing.size:
        raise LocalizationError("unobserved", ids[missing], "no robot observed them")
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
