"""Known answers for the performance metrics (Eq. 8, 24, 25; runtime/models/metrics.py), derived by hand.

The inputs have 3 robots and 4 configuration changes (n_r != n_d) with unequal distances,
so a mean taken as a median or a sum, the sum and the mean of Eq. 25 swapped, a wrong axis
or an |x| in place of the Euclidean norm all give a different number.
"""

from __future__ import annotations

import numpy as np
import pytest

from runtime.models.metrics import average_total_motion, localization_error, trajectory_following_performance

# True configurations of 3 robots before the trajectory and after each of n_d = 4 configurations (m).
#   robot A: (0,0) -> (3,4) -> (3,4)  -> (3,1)  -> (3,1)     moves 5, 0, 3, 0
#   robot B: (1,0) -> (1,1) -> (1,3)  -> (1,3)  -> (4,7)     moves 1, 2, 0, 5
#   robot C: (0,5) -> (0,5) -> (6,13) -> (6,13) -> (6,14)    moves 0, 10, 0, 1
TRUE_CONFIGS = np.array([
    [[0, 0], [1, 0], [0, 5]],
    [[3, 4], [1, 1], [0, 5]],
    [[3, 4], [1, 3], [6, 13]],
    [[3, 1], [1, 3], [6, 13]],
    [[3, 1], [4, 7], [6, 14]],
], dtype=float)

# Final desired positions: A off by (0.3, 0.4) -> 0.5 m, B by (0, 0.1) -> 0.1 m, C by (1.2, 0) -> 1.2 m.
FINAL_DESIRED = np.array([[3.3, 1.4], [4.0, 7.1], [7.2, 14.0]])


def test_eq8_localization_error_is_the_mean_euclidean_distance():
    """e_l = (1/n) sum_i |x_i - x^_i| (Eq. 8).

    Distances 0.5 (a 3-4-5 offset: |dx| + |dy| would give 0.7), 0.1 and 1.2 m:
    e_l = (0.5 + 0.1 + 1.2) / 3 = 0.6 m; the median would be 0.5, the sum 1.8.
    """
    assert localization_error(TRUE_CONFIGS[-1], FINAL_DESIRED) == pytest.approx(0.6, abs=1e-12)


def test_eq8_is_batched_over_leading_axes_and_averages_robots_only():
    """(S, n, 2) inputs give one e_l per sample: sample 0 as above (0.6 m), sample 1 every robot off by 2 m (2.0 m).

    Averaging over the samples instead of the robots would give (0.5+2)/2, (0.1+2)/2, (1.2+2)/2.
    """
    true = np.stack([TRUE_CONFIGS[-1], TRUE_CONFIGS[-1]])
    est = np.stack([FINAL_DESIRED, TRUE_CONFIGS[-1] + [0.0, 2.0]])
    np.testing.assert_allclose(localization_error(true, est), [0.6, 2.0], rtol=0, atol=1e-12)


def test_eq25_average_total_motion_sums_over_configurations_the_mean_over_robots():
    """m_bar = sum_j (1/n) sum_i |x_ji - x_(j-1)i| (Eq. 25).

    Per configuration change the robots move (5, 1, 0), (0, 2, 10), (3, 0, 0), (0, 5, 1) m;
    the means are 2, 4, 1, 2 and m_bar = 9 m. Swapped sum and mean: (6 + 12 + 3 + 6) / 4 = 6.75;
    medians over robots: 1 + 2 + 0 + 1 = 4; mean over everything: 27 / 12 = 2.25.
    """
    assert average_total_motion(TRUE_CONFIGS) == pytest.approx(9.0, abs=1e-12)


def test_eq25_is_batched_over_the_axes_between_configurations_and_robots():
    """(n_d + 1, S, n, 2): sample 1 is sample 0 scaled by 2, so m_bar = (9, 18) m."""
    batched = np.stack([TRUE_CONFIGS, 2.0 * TRUE_CONFIGS], axis=1)
    np.testing.assert_allclose(average_total_motion(batched), [9.0, 18.0], rtol=0, atol=1e-12)


def test_eq24_trajectory_following_performance():
    """P_f = e(final true, final desired) / m_bar (Eq. 24) = 0.6 / 9 = 1/15.

    Not normalised (0.6), normalised by the swapped Eq. 25 (0.6 / 6.75 = 0.0889) or by the sum of
    the final errors (1.8 / 9 = 0.2) all differ.
    """
    pf = trajectory_following_performance(TRUE_CONFIGS[-1], FINAL_DESIRED, TRUE_CONFIGS)
    assert pf == pytest.approx(1.0 / 15.0, abs=1e-12)


def test_eq24_batched_over_samples():
    """Two samples: (0.6 / 9, 0.6 x 2 / 18): scaling every position by 2 leaves P_f unchanged."""
    final_true = np.stack([TRUE_CONFIGS[-1], 2.0 * TRUE_CONFIGS[-1]])
    final_desired = np.stack([FINAL_DESIRED, 2.0 * FINAL_DESIRED])
    configs = np.stack([TRUE_CONFIGS, 2.0 * TRUE_CONFIGS], axis=1)
    np.testing.assert_allclose(trajectory_following_performance(final_true, final_desired, configs), [1 / 15, 1 / 15], atol=1e-12)
