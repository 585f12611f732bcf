"""Property-based tests of the weighted rigid superimposition (Eq. 21-22)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from hypothesis.extra.numpy import arrays

from coordinator.localization.superimpose import fusion_weights, superimpose
from runtime.errors import LocalizationError
from runtime.models.geometry import rotate, wrap_angle

coords = st.floats(-10, 10, allow_nan=False, allow_infinity=False)
sizes = st.integers(3, 25)


@st.composite
def point_sets(draw):
    n = draw(sizes)
    p = draw(arrays(np.float64, (n, 2), elements=coords))
    w = draw(arrays(np.float64, (n,), elements=st.floats(0.01, 100)))
    spread = np.sum(w[:, None] * (p - np.average(p, axis=0, weights=w)) ** 2) / w.sum()
    if spread < 1e-3:
        p = p + np.arange(n)[:, None] * np.array([0.3, -0.2])
    return p, w


def cost(p, q, w, theta, t):
    return float(np.sum(w * np.sum((rotate(theta, p) + t - q) ** 2, axis=1)))


@settings(max_examples=150, deadline=None)
@given(point_sets(), st.floats(-np.pi, np.pi), coords, coords)
def test_exact_rigid_motion_is_recovered(pw, theta, tx, ty):
    p, w = pw
    t = np.array([tx, ty])
    q = rotate(theta, p) + t
    got_theta, got_t = superimpose(p, q, w)
    assert abs(wrap_angle(got_theta - theta)) < 1e-9
    np.testing.assert_allclose(got_t, t, atol=1e-7)


@settings(max_examples=150, deadline=None)
@given(point_sets(), st.floats(-np.pi, np.pi), st.integers(0, 2**31))
def test_solution_is_a_minimum_of_the_weighted_cost(pw, theta, seed):
    p, w = pw
    rng = np.random.default_rng(seed)
    q = rotate(theta, p) + rng.normal(0, 0.5, p.shape)
    best_theta, best_t = superimpose(p, q, w)
    best = cost(p, q, w, best_theta, best_t)
    for _ in range(10):
        d_theta, d_t = rng.normal(0, 0.05), rng.normal(0, 0.05, 2)
        assert cost(p, q, w, best_theta + d_theta, best_t + d_t) >= best - 1e-9 * max(best, 1.0)


@settings(max_examples=80, deadline=None)
@given(point_sets(), st.floats(0.001, 1000), st.integers(0, 2**31))
def test_scaling_all_weights_changes_nothing(pw, scale, seed):
    p, w = pw
    q = p[::-1] + np.random.default_rng(seed).normal(0, 1, p.shape)
    a = superimpose(p, q, w)
    b = superimpose(p, q, w * scale)
    assert abs(wrap_angle(a[0] - b[0])) < 1e-9
    np.testing.assert_allclose(a[1], b[1], atol=1e-8)


def test_batch_equals_one_at_a_time():
    rng = np.random.default_rng(0)
    p, q, w = rng.normal(size=(4, 7, 2)), rng.normal(size=(4, 7, 2)), rng.uniform(0.1, 1, (4, 7))
    theta, t = superimpose(p, q, w)
    for k in range(4):
        tk, ttk = superimpose(p[k], q[k], w[k])
        assert theta[k] == pytest.approx(tk)
        np.testing.assert_allclose(t[k], ttk)


def test_coincident_points_are_degenerate():
    with pytest.raises(LocalizationError, match="degenerate"):
        superimpose(np.ones((4, 2)), np.zeros((4, 2)), np.ones(4))


def test_weights_follow_eq_22():
    np.testing.assert_allclose(fusion_weights(np.array([0.01, 0.0]), np.array([0.03, 0.0])), [25.0, 1e9])


def test_a_spread_of_exactly_min_spread_is_degenerate():
    """Two equally weighted points at (+-1e-6, 0) have the weighted spread 0.5 (1e-6)^2 + 0.5 (1e-6)^2 = 1e-12
    m^2 (exact in floating point) = MIN_SPREAD: the rotation is undetermined and the error says so. At
    (+-2e-6, 0) (spread 4e-12) the pair defines the rotation: 90 degrees onto (0, +-2e-6)."""
    from coordinator.localization.superimpose import MIN_SPREAD, weighted_procrustes

    p = np.array([[1e-6, 0.0], [-1e-6, 0.0]])
    assert weighted_procrustes(p, p, np.ones(2))[2] == MIN_SPREAD == 1e-12
    with pytest.raises(LocalizationError) as err:
        superimpose(p, p, np.ones(2))
    assert str(err.value) == "degenerate: robots [] (all topology points coincide: rotation is undetermined)"
    theta, t = superimpose(2 * p, np.array([[0.0, 2e-6], [0.0, -2e-6]]), np.ones(2))
    assert theta == pytest.approx(np.pi / 2, abs=1e-9)
    np.testing.assert_allclose(t, 0.0, atol=1e-15)
