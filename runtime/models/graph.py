"""Connected components of an undirected graph given by its edge list (robots as nodes)."""

from __future__ import annotations

import numpy as np


def component_labels(n: int, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """Component label per node of the undirected graph on nodes 0..n-1 with edges (i[k], j[k]):
    0, 1, ... numbered by each component's lowest node.

    Minima propagate along the edges with pointer jumping: each round a node takes the lowest
    label among itself and its neighbours, then the label of the node that label names (a node of
    its own component with a label no higher). Labels only fall and stop when every edge joins
    equal labels; the common label of a component is then its lowest node.
    """
    labels = np.arange(n)
    while True:
        lower = labels.copy()
        np.minimum.at(lower, i, labels[j])
        np.minimum.at(lower, j, labels[i])
        lower = lower[lower]
        if np.array_equal(lower, labels):
            return np.unique(labels, return_inverse=True)[1]
        labels = lower
