"""Performance metrics of the paper (positions in metres; arrays (..., n, 2))."""

from __future__ import annotations

from typing import cast

import numpy as np


def localization_error(true_positions: np.ndarray, estimated_positions: np.ndarray) -> np.ndarray:
    """e_l (Eq. 8): mean distance between true and estimated robot positions (m)."""
    return cast(np.ndarray, np.mean(np.linalg.norm(true_positions - estimated_positions, axis=-1), axis=-1))


def average_total_motion(true_configurations: np.ndarray) -> np.ndarray:
    """m_bar (Eq. 25): sum over configurations of the mean robot displacement (m).

    ``true_configurations`` is (n_d + 1, ..., n, 2): the true configuration before the
    trajectory, then after all steps towards each desired configuration.
    """
    steps = np.linalg.norm(np.diff(true_configurations, axis=0), axis=-1)
    return cast(np.ndarray, np.sum(np.mean(steps, axis=-1), axis=0))


def trajectory_following_performance(
    final_true: np.ndarray, final_desired: np.ndarray, true_configurations: np.ndarray
) -> np.ndarray:
    """P_f (Eq. 24): mean final true-vs-desired distance normalised by m_bar (dimensionless)."""
    return cast(np.ndarray, localization_error(final_true, final_desired) / average_total_motion(true_configurations))
