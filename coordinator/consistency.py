"""Consistency of the reported uncertainty along trajectories: normalised estimation error squared (NEES).

For one run (a trajectory, an anchor method, a localizer) the position NEES after
configuration c is the mean over robots of e_i^T P_i^-1 e_i, with e_i the true minus the
estimated position of robot i (m) and P_i its reported 2x2 position covariance (m^2).
For a consistent estimator it has expected value 2 (two position components); this module
reports NEES / 2, which should be near 1. Averaged over n robots and T trajectories, and
if those errors were independent, 2 n T (NEES / 2) follows a chi-square law with 2 n T
degrees of freedom: ``chi2_band`` gives the 95 % band of the average. Errors of robots
of one swarm are correlated (a common drift), so the band is a guide, not a test.
"""

from __future__ import annotations

import numpy as np
from scipy.stats import chi2

from coordinator.run_result import RunResult

METHODS = ("no-anchors", "ref57", "heuristic-fixed", "one-at-a-time")  # fixed plans; add inchworm with --methods


def position_nees(truth: np.ndarray, poses: np.ndarray, cov: np.ndarray) -> float:
    """Mean over robots of e^T P^-1 e / 2 for positions: truth/poses (n, >=2) m, cov (n, 3, 3).

    A singular reported covariance with a non-zero error gives inf (an overconfident 0 variance).
    """
    e = truth[:, :2] - poses[:, :2]
    p = cov[:, :2, :2]
    det = p[:, 0, 0] * p[:, 1, 1] - p[:, 0, 1] * p[:, 1, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        q = (p[:, 1, 1] * e[:, 0] ** 2 - 2 * p[:, 0, 1] * e[:, 0] * e[:, 1] + p[:, 0, 0] * e[:, 1] ** 2) / det
    q = np.where(det > 0, q, np.inf)
    return float(np.mean(q) / 2.0)


def run_nees(result: RunResult) -> np.ndarray:
    """Position NEES / 2 after each configuration of a simulated run (K,)."""
    return np.array([position_nees(c.truth, c.estimate.poses, c.estimate.cov) for c in result.configs])  # type: ignore[arg-type]  # simulated: truth known


def chi2_band(robots: int, trajectories: int, level: float = 0.95) -> tuple[float, float]:
    """95 % band of the mean of robots x trajectories independent NEES / 2 values (each chi2(2) / 2)."""
    dof = 2 * robots * trajectories
    tail = (1.0 - level) / 2.0
    return float(chi2.ppf(tail, dof) / dof), float(chi2.ppf(1.0 - tail, dof) / dof)


__all__ = ["chi2_band", "position_nees", "run_nees", "METHODS"]
