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

from coordinator.localization.dead_reckoning import dead_reckon_arrays
from coordinator.localization.range_bearing import DIST_FLOOR, bearing_weights, observation_jacobian, prior_information, sensor_sigmas
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
    Fisher information (``localization.crlb.fisher_information``: the dead-reckoning prior ``prior_cov`` (c, n, 3, 3)
    and a range and a bearing between every two robots within sensing range at ``poses`` (c, n, 3)), assembled densely
    (the same matrix as the sparse assembly, to rounding)."""
    c, n, _ = poses.shape
    d = poses[:, None, :, :2] - poses[:, :, None, :2]  # [c, i, j] = x_j - x_i: observer i, observed j
    seen = (np.linalg.norm(d, axis=-1) <= cfg.sensing_range_m) & ~np.eye(n, dtype=bool)
    rho = np.hypot(d[..., 0], d[..., 1])
    s_r, _ = sensor_sigmas(cfg)
    w_b = np.where(seen, bearing_weights(rho, cfg), 0.0)
    range_x, range_y, bearing_x, bearing_y = observation_jacobian(d[..., 0], d[..., 1], 1.0 / np.maximum(rho, DIST_FLOOR), seen / s_r, w_b)
    along = np.stack([range_x, range_y], axis=-1)  # d range / d x_j (c, n, n, 2); d / d x_i = -d / d x_j
    across = np.stack([bearing_x, bearing_y], axis=-1)  # d bearing / d x_j; d bearing / d theta_i = -w_b
    pair = along[..., :, None] * along[..., None, :] + across[..., :, None] * across[..., None, :]  # (c, n, n, 2, 2)
    heading = -w_b[..., None] * across  # theta_i against x_j (c, n, n, 2)
    blocks = np.zeros((c, n, n, 3, 3))
    blocks[..., :2, :2] = -(pair + np.swapaxes(pair, 1, 2))
    blocks[..., 2, :2] = heading
    blocks[..., :2, 2] = np.swapaxes(heading, 1, 2)
    own = prior_information(prior_cov).copy()  # (c, n, 3, 3)
    own[..., :2, :2] += pair.sum(axis=2) + pair.sum(axis=1)
    own[..., 2, :2] -= heading.sum(axis=2)
    own[..., :2, 2] -= heading.sum(axis=2)
    own[..., 2, 2] += np.einsum("cij,cij->ci", w_b, w_b)
    index = np.arange(n)
    blocks[:, index, index] = own
    full = np.linalg.inv(blocks.transpose(0, 1, 3, 2, 4).reshape(c, 3 * n, 3 * n)).reshape(c, n, 3, n, 3)
    out = full[:, index, :, index, :].transpose(1, 0, 2, 3)  # (c, n, 3, 3)
    return np.asarray(0.5 * (out + np.swapaxes(out, -1, -2)))
