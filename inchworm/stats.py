"""The statistics of the comparisons: confidence interval of a mean and the paired t-test."""

from __future__ import annotations

import numpy as np

CONFIDENCE = 0.97  # Table II of the paper


def mean_ci(values: np.ndarray, confidence: float = CONFIDENCE) -> tuple[float, float]:
    """Student-t ``confidence`` interval of the mean of ``values``; (nan, nan) for fewer than two values.

    Symmetric about the mean, so for a quantity >= 0 (P_f) its lower end can be negative;
    ``clipped_at_zero`` gives the interval a plot shows.
    """
    from scipy import stats  # noqa: PLC0415 - scipy only when statistics are computed

    v = np.asarray(values, float)
    if len(v) < 2:
        return float("nan"), float("nan")
    half = stats.t.ppf(0.5 + confidence / 2, len(v) - 1) * v.std(ddof=1) / np.sqrt(len(v))
    return float(v.mean() - half), float(v.mean() + half)


def clipped_at_zero(low: float, high: float) -> tuple[float, float]:
    """An interval of a quantity that cannot be negative, its lower end clipped at 0."""
    return max(low, 0.0), high


def paired_p_value(a: np.ndarray, b: np.ndarray) -> float:
    """Two-sided p-value of the paired t-test of ``a`` against ``b`` (same trajectories, same order)."""
    from scipy import stats  # noqa: PLC0415

    return float(stats.ttest_rel(np.asarray(a, float), np.asarray(b, float)).pvalue)
