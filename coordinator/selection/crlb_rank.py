"""Predicted e_l of a plan from the localizer's information matrix, without sampling (``--selection crlb``).

For each step of a plan the expected post-step poses are the noise-free execution of
the commands (mobile robots at their desired positions, Phase 1.1), the dead-reckoning
covariance is propagated to first order (``dead_reckon_arrays``), and the posterior
covariance is the Cramer-Rao bound of that step (``crlb_pose_covariances``: the
dead-reckoning prior plus every range/bearing observation between robots within
sensing range of each other at the expected poses). Its per-robot blocks are the next
step's prior, as the localizers carry them. The predicted e_l (Eq. 8) is the mean over
robots of E|e_i| = sqrt(pi) / 2 x sqrt(trace of the position block), exact for an
isotropic Gaussian error.

Approximations: the bound is what the joint localizer reaches (about 1.0-1.06 of it,
README); the paper's localizer stays 1.5-2.7x above it, so with ``--localizer paper``
this ranks plans by what the information allows, not by what Eq. 23 makes of it.
Observation dropout is ignored, and cross-robot correlations are dropped between steps.
"""

from __future__ import annotations

import math

import numpy as np

from coordinator.localization.crlb import crlb_pose_covariances
from coordinator.localization.dead_reckoning import dead_reckon_arrays
from coordinator.plan import Plan
from runtime.models.config import ModelConfig
from runtime.models.motion import command_towards
from runtime.models.state import SwarmEstimate

MEAN_NORM = math.sqrt(math.pi) / 2  # E|e| / sqrt(E|e|^2) for an isotropic 2-D Gaussian


def predicted_errors(cfg: ModelConfig, estimate: SwarmEstimate, desired: np.ndarray, plans: list[Plan]) -> np.ndarray:
    """Predicted e_l (m) of each plan for moving from ``estimate`` to ``desired`` (n, 2)."""
    return np.array([predicted_error(cfg, estimate, desired, np.stack([p.moving(k) for k in range(p.n_steps)])) for p in plans])


def predicted_error(cfg: ModelConfig, estimate: SwarmEstimate, desired: np.ndarray, steps: np.ndarray) -> float:
    """Predicted e_l (m) of the plan whose step k moves the robots where ``steps[k]`` (n,) is True."""
    poses, cov = estimate.poses.copy(), estimate.cov.copy()
    off_diagonal = ~np.eye(len(poses), dtype=bool)
    for moving in steps:
        poses, cov = dead_reckon_arrays(poses, cov, command_towards(poses, desired), moving, cfg)
        gap = np.linalg.norm(poses[:, None, :2] - poses[None, :, :2], axis=-1)
        observer, observed = np.nonzero((gap <= cfg.sensing_range_m) & off_diagonal)
        cov = crlb_pose_covariances(poses, cov, observer, observed, cfg)
    return float(MEAN_NORM * np.mean(np.sqrt(cov[:, 0, 0] + cov[:, 1, 1])))
