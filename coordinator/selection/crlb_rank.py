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

from coordinator.localization.crlb import fisher_informations
from coordinator.localization.dead_reckoning import dead_reckon_arrays
from coordinator.plan import Plan
from runtime.models.config import ModelConfig
from runtime.models.motion import command_towards
from runtime.models.state import SwarmEstimate

MEAN_NORM = math.sqrt(math.pi) / 2  # E|e| / sqrt(E|e|^2) for an isotropic 2-D Gaussian
CHUNK = 256  # plans predicted together


def predicted_errors(cfg: ModelConfig, estimate: SwarmEstimate, desired: np.ndarray, plans: list[Plan]) -> np.ndarray:
    """Predicted e_l (m) of each plan for moving from ``estimate`` to ``desired`` (n, 2), the plans side by side."""
    out = []
    for first in range(0, len(plans), CHUNK):
        chunk = plans[first : first + CHUNK]
        steps = np.zeros((len(chunk), max(p.n_steps for p in chunk), estimate.n), bool)
        for k, plan in enumerate(chunk):
            steps[k, : plan.n_steps] = np.stack([plan.moving(s) for s in range(plan.n_steps)])
        out.append(_predicted(cfg, estimate, desired, steps, np.array([p.n_steps for p in chunk])))
    return np.concatenate(out) if out else np.zeros(0)


def predicted_error(cfg: ModelConfig, estimate: SwarmEstimate, desired: np.ndarray, steps: np.ndarray) -> float:
    """Predicted e_l (m) of the plan whose step k moves the robots where ``steps[k]`` (n,) is True."""
    return float(_predicted(cfg, estimate, desired, np.asarray(steps, bool)[None], np.array([len(steps)]))[0])


def _predicted(cfg: ModelConfig, estimate: SwarmEstimate, desired: np.ndarray, steps: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Predicted e_l (m) of plans (c,) whose step k moves ``steps[:, k]`` (c, k, n); plan p has ``counts[p]`` steps."""
    c, n = len(steps), estimate.n
    poses = np.broadcast_to(estimate.poses, (c, n, 3)).copy()
    cov = np.broadcast_to(estimate.cov, (c, n, 3, 3)).copy()
    for k in range(steps.shape[1]):
        live = np.flatnonzero(counts > k)
        moved, moved_cov = dead_reckon_arrays(poses[live], cov[live], command_towards(poses[live], desired), steps[live, k], cfg)
        poses[live], cov[live] = moved, crlb_blocks(moved, moved_cov, cfg)
    return np.asarray(MEAN_NORM * np.mean(np.sqrt(cov[..., 0, 0] + cov[..., 1, 1]), axis=-1))


def crlb_blocks(poses: np.ndarray, prior_cov: np.ndarray, cfg: ModelConfig) -> np.ndarray:
    """The Cramer-Rao bound of one step of c swarms at once: the 3x3 diagonal blocks (c, n, 3, 3) of the inverse of the
    Fisher information (``localization.crlb.fisher_informations``: the dead-reckoning prior ``prior_cov`` (c, n, 3, 3)
    and a range and a bearing between every two robots within sensing range at ``poses`` (c, n, 3))."""
    c, n, _ = poses.shape
    gap = np.linalg.norm(poses[:, None, :, :2] - poses[:, :, None, :2], axis=-1)
    swarm, observer, observed = np.nonzero((gap <= cfg.sensing_range_m) & ~np.eye(n, dtype=bool))
    full = np.linalg.inv(fisher_informations(poses, prior_cov, swarm, observer, observed, cfg)).reshape(c, n, 3, n, 3)
    index = np.arange(n)
    out = full[:, index, :, index, :].transpose(1, 0, 2, 3)  # (c, n, 3, 3)
    return np.asarray(0.5 * (out + np.swapaxes(out, -1, -2)))
