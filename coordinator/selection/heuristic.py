"""Heuristic initial guess for the anchors of every step (Section 4.2.3, Eq. 11-13).

For step k the anchors R_ak should be spread out (distribution d_k, Eq. 11: mean
distance of the anchors from their centroid) and close to the mobile robots
(separation s_k, Eq. 12: distance between the anchor and mobile centroids), measured
in the expected post-step configuration: mobile robots at their desired positions,
robots that moved earlier at theirs, the others where they are estimated now. Each
step's mobile group maximises p_ak = d_k + 1 / s_k (Eq. 13), step after step.
Small choices are enumerated; large ones are improved by steepest-ascent single swaps
from the robots nearest the centroid (only the swaps that can score best are scored in
full, ``_promising_swaps``).
"""

from __future__ import annotations

import itertools
import math
from typing import cast

import numpy as np

from coordinator.plan import Plan

ENUMERATE_LIMIT = 4000  # candidate groups evaluated exhaustively per step
MIN_SEPARATION = 1e-9  # m, keeps 1 / s_k finite
SWAP_CHUNK = 1 << 16  # single swaps bounded at a time (``_promising_swaps``): memory stays small for large swarms
ROW_SLACK = 1e-9  # relative slack of the per-row bounds that skip rows (``_row_bounds``): far above rounding (~1e-15)


def step_score(groups: np.ndarray, base: np.ndarray, desired: np.ndarray) -> np.ndarray:
    """p_ak (Eq. 13) for candidate mobile groups given as masks (C, n).

    ``base`` (n, 2) holds the expected positions of robots that do not move in this step.
    """
    anchors = ~groups
    n_a = np.maximum(anchors.sum(axis=1, keepdims=True), 1)
    centroid_a = anchors @ base / n_a
    d = np.sum(anchors * np.linalg.norm(base[None] - centroid_a[:, None], axis=-1), axis=1) / n_a[:, 0]  # Eq. 11
    centroid_m = groups @ desired / np.maximum(groups.sum(axis=1, keepdims=True), 1)
    s = np.linalg.norm(centroid_a - centroid_m, axis=1)  # Eq. 12
    return cast(np.ndarray, d + 1.0 / np.maximum(s, MIN_SEPARATION))


def _best_group(pool: np.ndarray, size: int, base: np.ndarray, desired: np.ndarray) -> np.ndarray:
    n = len(base)
    if math.comb(len(pool), size) <= ENUMERATE_LIMIT:
        combos = np.array(list(itertools.combinations(pool, size)), dtype=np.int64)
        masks = np.zeros((len(combos), n), bool)
        masks[np.arange(len(combos))[:, None], combos] = True
        return cast(np.ndarray, combos[int(np.argmax(step_score(masks, base, desired)))])
    centre = base.mean(axis=0)
    group = pool[np.argsort(np.linalg.norm(desired[pool] - centre, axis=1), kind="stable")[:size]]
    best = step_score(_mask(group, n), base, desired)[0]
    for _ in range(4 * size):
        outside = np.setdiff1d(pool, group)
        swaps = _promising_swaps(group, outside, base, desired)
        masks = np.repeat(_mask(group, n), len(swaps), axis=0)
        masks[np.arange(len(swaps)), group[swaps // len(outside)]] = False
        masks[np.arange(len(swaps)), outside[swaps % len(outside)]] = True
        scores = step_score(masks, base, desired)
        k = int(np.argmax(scores))
        if scores[k] <= best:
            break
        best = scores[k]
        group = group.copy()
        group[swaps[k] // len(outside)] = outside[swaps[k] % len(outside)]
    return group


def _promising_swaps(group: np.ndarray, outside: np.ndarray, base: np.ndarray, desired: np.ndarray) -> np.ndarray:
    """Flat indices a x len(outside) + b of the single swaps (group[a] out, outside[b] in) that can score best.

    Eq. 12 after a swap is exact in O(1) per swap (both centroids shift by one robot). Eq. 11's
    sum of anchor distances to the shifted centroid c + delta is bounded below by its tangent
    at c (it is convex in the centroid) and above by the tangent plus a curvature bound. A
    swap whose upper bound is below the best lower bound cannot be the best single swap, so
    the exact scores of the rest (``step_score``) pick the same swap as scoring all of them:
    O(size x outside) instead of O(size x outside x n), in chunks of ``SWAP_CHUNK`` swaps, and only for the rows
    (robots leaving) whose bounds over all their swaps (``_row_bounds``) can reach the best: the same swaps.
    """
    n = len(base)
    anchor = np.ones(n, bool)
    anchor[group] = False
    n_a, n_m = n - len(group), len(group)
    centroid_a = base[anchor].mean(axis=0)
    off = base[anchor] - centroid_a
    dist = np.hypot(off[:, 0], off[:, 1])
    total = dist.sum()
    pull = np.sum(off / np.maximum(dist, MIN_SEPARATION)[:, None], axis=0)  # minus the gradient of the sum at c
    out_, in_ = base[group] - centroid_a, base[outside] - centroid_a  # robots leaving the group / joining it
    leave = base[group] / n_a + desired[group] / n_m  # Eq. 12 gap c_a' - c_m' = c_a - c_m + leave[a] - join[b]
    join = base[outside] / n_a + desired[outside] / n_m
    lead = centroid_a - desired[group].mean(axis=0) + leave
    # Rows of ``group`` in chunks of about SWAP_CHUNK swaps, the same numbers as all at once in bounded memory; rows that
    # cannot matter are skipped by bounds that hold for every swap of the row (``_row_bounds``), with a slack far
    # above rounding: the same swaps and the same numbers as scoring every row.
    size = max(1, SWAP_CHUNK // len(outside))

    def chunks(rows: np.ndarray) -> list[np.ndarray]:
        return [rows[k:k + size] for k in range(0, len(rows), size)]

    def shift(r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # (rows, outside): the swap's anchor-centroid shift delta
        return (out_[r, 0, None] - in_[None, :, 0]) / n_a, (out_[r, 1, None] - in_[None, :, 1]) / n_a

    def bounds(r: np.ndarray) -> np.ndarray:  # (rows, outside): each swap's lower bound of the best score
        dx, dy = shift(r)
        tangent = total - dx * pull[0] - dy * pull[1] + np.hypot(out_[r, 0, None] - dx, out_[r, 1, None] - dy) \
            - np.hypot(in_[None, :, 0] - dx, in_[None, :, 1] - dy)
        inverse_s = 1.0 / np.maximum(np.hypot(lead[r, 0, None] - join[None, :, 0], lead[r, 1, None] - join[None, :, 1]),
                                     MIN_SEPARATION)
        return cast(np.ndarray, tangent / n_a + inverse_s)

    reach, top = _row_bounds(out_, in_, lead, join, total, pull, n_a)
    far = int(np.argmax(reach))
    widest = float(np.max(sum(d * d for d in shift(np.array([far])))))  # one row's largest shift, squared
    rows = np.flatnonzero(reach * reach >= widest * (1.0 - ROW_SLACK))  # the only rows that can shift further
    step = float(np.sqrt(max(float(np.max(dx * dx + dy * dy)) for dx, dy in map(shift, chunks(rows)))))
    room = dist - step
    curvature = np.sum(np.where(room > 0, step * step / (2 * np.maximum(room, MIN_SEPARATION)), 2 * step))
    margin = (curvature + 1e-9 * (1 + total)) / n_a
    first = float(bounds(np.argsort(-top, kind="stable")[:size]).max())  # the rows of the highest bounds first
    rows = np.flatnonzero(top + margin + ROW_SLACK * (1.0 + abs(first)) >= first)
    best, kept, lows = -np.inf, [], []
    for r in chunks(rows):
        low = bounds(r)
        best = max(best, float(low.max()))
        k, b = np.nonzero(low + margin >= best)
        kept.append(r[k] * len(outside) + b)
        lows.append(low[k, b])
    flat, low = np.concatenate(kept), np.concatenate(lows)
    return cast(np.ndarray, flat[low + margin >= best])


def _row_bounds(out_: np.ndarray, in_: np.ndarray, lead: np.ndarray, join: np.ndarray, total: float, pull: np.ndarray,
                n_a: int) -> tuple[np.ndarray, np.ndarray]:
    """Per robot a leaving the group, upper bounds over every robot b joining it: of |delta| = |out_a - in_b| / n_a
    (the triangle inequality) and of the swap's lower bound of ``_promising_swaps``: its tangent term is at most
    total + |out_a| - |in_b| + |delta| (|pull| + 2) and 1 / s at most 1 / (the distance from lead_a to the nearest
    join_b, from a k-d tree)."""
    from scipy.spatial import cKDTree  # noqa: PLC0415 - scipy only when swaps are bounded

    out_len, in_len = np.hypot(out_[:, 0], out_[:, 1]), np.hypot(in_[:, 0], in_[:, 1])
    reach = (out_len + in_len.max()) / n_a
    nearest, _ = cKDTree(join).query(lead)
    tangent = total + out_len - in_len.min() + reach * (float(np.hypot(pull[0], pull[1])) + 2.0)
    return reach, tangent / n_a + 1.0 / np.maximum(nearest, MIN_SEPARATION)


def _mask(group: np.ndarray, n: int) -> np.ndarray:
    m = np.zeros((1, n), bool)
    m[0, group] = True
    return m


def heuristic_plan(current: np.ndarray, desired: np.ndarray, n_anchors: int) -> Plan:
    """The heuristic plan for moving from ``current`` to ``desired`` positions (n, 2) with n_a anchors."""
    n = len(current)
    size = n - n_anchors
    base = np.array(current, dtype=float)
    pool = np.arange(n)
    order = []
    while len(pool) > size:
        group = _best_group(pool, size, base, desired)
        order.extend(sorted(group.tolist()))
        base[group] = desired[group]
        pool = np.setdiff1d(pool, group)
    order.extend(pool.tolist())
    return Plan.equal(np.array(order), n_anchors)
