"""Eq. 8, 24, 25 on hand-computed examples."""

from __future__ import annotations

import numpy as np
import pytest

from runtime.models.metrics import average_total_motion, localization_error, trajectory_following_performance


def test_localization_error_eq8():
    true = np.array([[0.0, 0.0], [1.0, 1.0]])
    est = np.array([[0.3, 0.4], [1.0, 1.0]])
    assert localization_error(true, est) == pytest.approx(0.25)


def test_average_total_motion_eq25_and_pf_eq24():
    configs = np.array([[[0, 0], [1, 0]], [[0, 1], [1, 1]], [[0, 1], [1, 3]]], float)  # (n_d + 1, n, 2)
    assert average_total_motion(configs) == pytest.approx(1.0 + 1.0)
    desired = np.array([[0, 1.2], [1, 3]], float)
    assert trajectory_following_performance(configs[-1], desired, configs) == pytest.approx(0.1 / 2.0)


def test_metrics_broadcast_over_batches():
    true = np.zeros((3, 4, 2))
    est = np.ones((3, 4, 2))
    np.testing.assert_allclose(localization_error(true, est), np.full(3, np.sqrt(2)))
