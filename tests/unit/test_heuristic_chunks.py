"""The heuristic plan's single swaps, bounded in chunks (``SWAP_CHUNK``) and only for the rows whose bounds can reach
the best (``_row_bounds``), are the swaps of bounding every swap at once (the formula of ``_promising_swaps``)."""

import numpy as np
import pytest

import coordinator.selection.heuristic as heuristic
from coordinator.plan import feasible_anchor_counts
from coordinator.selection.heuristic import MIN_SEPARATION, _promising_swaps, heuristic_plan


def every_swap(group: np.ndarray, outside: np.ndarray, base: np.ndarray, desired: np.ndarray) -> np.ndarray:
    """``_promising_swaps`` by its formula, every swap bounded at once (full (size, outside) arrays)."""
    n = len(base)
    anchor = np.ones(n, bool)
    anchor[group] = False
    n_a, n_m = n - len(group), len(group)
    centroid_a = base[anchor].mean(axis=0)
    off = base[anchor] - centroid_a
    dist = np.hypot(off[:, 0], off[:, 1])
    total = dist.sum()
    pull = np.sum(off / np.maximum(dist, MIN_SEPARATION)[:, None], axis=0)
    out_, in_ = base[group] - centroid_a, base[outside] - centroid_a
    dx = (out_[:, 0, None] - in_[None, :, 0]) / n_a
    dy = (out_[:, 1, None] - in_[None, :, 1]) / n_a
    tangent = total - dx * pull[0] - dy * pull[1] + np.hypot(out_[:, 0, None] - dx, out_[:, 1, None] - dy) \
        - np.hypot(in_[None, :, 0] - dx, in_[None, :, 1] - dy)
    step = float(np.sqrt(np.max(dx * dx + dy * dy)))
    room = dist - step
    curvature = np.sum(np.where(room > 0, step * step / (2 * np.maximum(room, MIN_SEPARATION)), 2 * step))
    leave = base[group] / n_a + desired[group] / n_m
    join = base[outside] / n_a + desired[outside] / n_m
    lead = centroid_a - desired[group].mean(axis=0) + leave
    inverse_s = 1.0 / np.maximum(np.hypot(lead[:, 0, None] - join[None, :, 0], lead[:, 1, None] - join[None, :, 1]), MIN_SEPARATION)
    low = (tangent / n_a + inverse_s).ravel()
    return np.flatnonzero(low + (curvature + 1e-9 * (1 + total)) / n_a >= low.max())


def rough_change(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """A change of ``n`` robots with a crowd on one point (zero distances), robots that do not move, long drives."""
    rng = np.random.default_rng(seed)
    current = rng.uniform(0.0, 0.3 * np.sqrt(n), (n, 2))
    current[: n // 4] = current[0]  # a quarter of the swarm on one spot
    desired = current + rng.normal(0.0, 0.2, (n, 2)) * rng.choice([0.0, 1.0, 5.0], (n, 1))
    return current, desired


@pytest.mark.parametrize("n, seed", [(12, 0), (60, 1), (150, 2)])
def test_bounded_rows_give_the_swaps_of_every_swap(monkeypatch: pytest.MonkeyPatch, n: int, seed: int) -> None:
    current, desired = rough_change(n, seed)
    rng = np.random.default_rng(seed)
    plans = {n_a: heuristic_plan(current, desired, n_a).order for n_a in feasible_anchor_counts(n)[1:4]}
    for group in (np.sort(rng.choice(n, n // 2, replace=False)), np.arange(n // 3), np.arange(n - 3, n)):
        outside = np.setdiff1d(np.arange(n), group)
        whole = every_swap(group, outside, current, desired)
        for chunk in (1, 3 * len(outside) + 1, 10**9):  # one row of swaps a chunk (the least), three rows, all rows
            monkeypatch.setattr(heuristic, "SWAP_CHUNK", chunk)
            assert np.array_equal(_promising_swaps(group, outside, current, desired), whole)
    for chunk in (1, 10**9):
        monkeypatch.setattr(heuristic, "SWAP_CHUNK", chunk)
        assert all(np.array_equal(heuristic_plan(current, desired, n_a).order, order) for n_a, order in plans.items())


def test_swaps_of_robots_at_one_point_and_exactly_apart() -> None:
    """Every robot leaving on one point, those joining exactly 2R-like distances apart on a line: ties everywhere."""
    base = np.concatenate([np.zeros((6, 2)), np.column_stack([np.arange(6) * 0.022, np.zeros(6)])])
    desired = base + [0.1, 0.0]
    group, outside = np.arange(6), np.arange(6, 12)
    assert np.array_equal(_promising_swaps(group, outside, base, desired), every_swap(group, outside, base, desired))
