"""The heuristic plan's single swaps bounded in chunks (``SWAP_CHUNK``) pick the same swaps as all at once."""

import numpy as np
import pytest

import coordinator.selection.heuristic as heuristic
from coordinator.plan import feasible_anchor_counts
from coordinator.selection.heuristic import _promising_swaps, heuristic_plan


def rough_change(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """A change of ``n`` robots with a crowd on one point (zero distances to the anchors' centroid's neighbours),
    robots that do not move and long drives."""
    rng = np.random.default_rng(seed)
    current = rng.uniform(0.0, 0.3 * np.sqrt(n), (n, 2))
    current[: n // 4] = current[0]  # a quarter of the swarm on one spot
    desired = current + rng.normal(0.0, 0.2, (n, 2)) * rng.choice([0.0, 1.0, 5.0], (n, 1))
    return current, desired


@pytest.mark.parametrize("n, seed", [(12, 0), (60, 1), (150, 2)])
def test_chunked_swaps_are_the_swaps_of_all_at_once(monkeypatch: pytest.MonkeyPatch, n: int, seed: int) -> None:
    current, desired = rough_change(n, seed)
    rng = np.random.default_rng(seed)
    group = np.sort(rng.choice(n, n // 2, replace=False))
    outside = np.setdiff1d(np.arange(n), group)
    whole = _promising_swaps(group, outside, current, desired)
    plans = {n_a: heuristic_plan(current, desired, n_a).order for n_a in feasible_anchor_counts(n)[1:4]}
    for chunk in (1, 3 * len(outside) + 1):  # one row of swaps a chunk (the least), three rows
        monkeypatch.setattr(heuristic, "SWAP_CHUNK", chunk)
        assert np.array_equal(_promising_swaps(group, outside, current, desired), whole)
        assert all(np.array_equal(heuristic_plan(current, desired, n_a).order, order) for n_a, order in plans.items())
