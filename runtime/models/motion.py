"""Turn-then-drive motion model with no odometry (Section 2, 6.1).

A command (turn, drive) is given in the robot's body frame: the robot first turns by
``turn`` (rad), then drives ``drive`` (m) straight along its new heading. Execution
adds zero-mean Gaussian noise to the turn and a relative Gaussian error to the drive.

``apply_motion`` is deterministic and broadcasts over any batch shape (robots x
Monte Carlo samples); ``draw_motion_noise`` is the only source of randomness, so the
same function serves the in-process simulator, the agents' simulated drivers and
the Monte Carlo planner.
"""

from __future__ import annotations

from typing import cast

import numpy as np

from runtime.models.config import ModelConfig
from runtime.models.geometry import wrap_angle


def apply_motion(
    poses: np.ndarray, commands: np.ndarray, turn_noise: np.ndarray | float = 0.0, drive_noise_frac: np.ndarray | float = 0.0
) -> np.ndarray:
    """Poses (..., 3) after executing body-frame ``commands`` (..., 2) = (turn rad, drive m).

    The executed turn is ``turn + turn_noise``; the executed distance is
    ``drive * (1 + drive_noise_frac)``; a zero command is no motion and adds no noise.
    With zero noise this is dead reckoning (Eq. 17-19).
    """
    moved = (commands[..., 0] != 0.0) | (commands[..., 1] != 0.0)
    heading = poses[..., 2] + commands[..., 0] + np.where(moved, turn_noise, 0.0)
    dist = commands[..., 1] * (1.0 + np.asarray(drive_noise_frac))
    out = np.empty(np.broadcast_shapes(poses.shape, commands.shape[:-1] + (3,)))
    out[..., 0] = poses[..., 0] + dist * np.cos(heading)
    out[..., 1] = poses[..., 1] + dist * np.sin(heading)
    out[..., 2] = wrap_angle(heading)
    return out


def draw_motion_noise(rng: np.random.Generator, shape: tuple[int, ...], cfg: ModelConfig) -> tuple[np.ndarray, np.ndarray]:
    """(turn noise rad, relative drive noise) of the given shape."""
    turn = rng.normal(0.0, 1.0, shape) * cfg.turn_sigma_rad
    drive = rng.normal(0.0, 1.0, shape) * cfg.drive_sigma_frac
    return turn, drive


def execute_command(pose: np.ndarray, command: np.ndarray, cfg: ModelConfig, rng: np.random.Generator) -> np.ndarray:
    """True pose (3,) of one robot after executing ``command`` with noise from its own ``rng``."""
    turn, drive = draw_motion_noise(rng, (), cfg)
    return apply_motion(pose, command, turn, drive)


def command_towards(pose: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Body-frame command(s) (..., 2) that take ``pose`` (..., 3) to ``target`` (..., 2) if executed exactly."""
    d = target - pose[..., :2]
    turn = wrap_angle(np.arctan2(d[..., 1], d[..., 0]) - pose[..., 2])
    dist = np.hypot(d[..., 0], d[..., 1])
    turn = np.where(dist > 0.0, turn, 0.0)
    return np.stack([turn, dist], axis=-1)


def motion_covariance(poses: np.ndarray, prior_cov: np.ndarray, commands: np.ndarray, cfg: ModelConfig) -> np.ndarray:
    """Covariance (..., 3, 3) of the pose after ``commands``, linearised at the commanded motion.

    Propagates the prior pose covariance and the turn/drive noise through
    ``apply_motion``: P' = Fx P Fx^T + Fu Q Fu^T (first-order, as in an EKF predict step).
    Robots with a zero command keep their prior covariance.
    """
    heading = poses[..., 2] + commands[..., 0]
    d = commands[..., 1]
    c, s = np.cos(heading), np.sin(heading)
    shape = poses.shape[:-1]
    fx = np.broadcast_to(np.eye(3), shape + (3, 3)).copy()
    fx[..., 0, 2] = -d * s
    fx[..., 1, 2] = d * c
    fu = np.zeros(shape + (3, 2))
    fu[..., 0, 0], fu[..., 1, 0], fu[..., 2, 0] = -d * s, d * c, 1.0
    fu[..., 0, 1], fu[..., 1, 1] = c * d, s * d
    q = np.zeros(shape + (2, 2))
    moved = (commands[..., 0] != 0.0) | (d != 0.0)
    q[..., 0, 0] = np.where(moved, cfg.turn_sigma_rad**2, 0.0)
    q[..., 1, 1] = cfg.drive_sigma_frac**2
    return cast(np.ndarray, fx @ prior_cov @ np.swapaxes(fx, -1, -2) + fu @ q @ np.swapaxes(fu, -1, -2))


def motion_moments(
    poses: np.ndarray, prior_cov: np.ndarray, commands: np.ndarray, cfg: ModelConfig
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact mean (..., 3), expected Jacobian Fx (..., 3, 3) and noise W (..., 3, 3) of the pose after ``commands``:
    its covariance is Fx P Fx^T + W exactly.

    The pre-step pose is Gaussian (``poses``, ``prior_cov`` P), the executed turn and relative drive errors are
    ``apply_motion``'s. The heading after the turn, phi = theta + turn + turn noise, is Gaussian with variance
    s^2 = P_theta + sigma_turn^2; the position p + d (1 + e) (cos phi, sin phi) is not (a banana when s is large), but
    its mean and covariance have a closed form. With k = exp(-s^2 / 2): the mean is p + d k u (u along the commanded
    heading), Fx is the first-order Jacobian with d replaced by d k, and by Stein's lemma Fx is also the exact
    regression of the post-step pose on the pre-step pose (Cov(x', x) = Fx Cov(p, x) for any x jointly Gaussian with
    it); W, the rest of the covariance, is uncorrelated with the pre-step pose (docs/localization.md has it written out).
    First order (``motion_covariance``) the position error across the heading is exactly d times the heading error and
    the product of the drive and heading errors is lost: at a 17 deg turn noise and a 28 % drive noise that covariance
    is several times overconfident. Robots with a zero command keep their pose (Fx = I, W = 0).
    """
    d = commands[..., 1]
    moved = (commands[..., 0] != 0.0) | (d != 0.0)
    turn_var = np.where(moved, cfg.turn_sigma_rad**2, 0.0)
    p_theta = prior_cov[..., 2, 2]
    s2 = p_theta + turn_var
    k2 = np.exp(-s2)  # k^2
    a = -np.expm1(-s2)  # 1 - k^2, accurate for small s
    dk = d * np.sqrt(k2)
    heading = poses[..., 2] + commands[..., 0]
    c, s = np.cos(heading), np.sin(heading)
    mean = np.array(poses, dtype=float, copy=True)
    mean[..., 0] += dk * c
    mean[..., 1] += dk * s
    mean[..., 2] = wrap_angle(heading)
    shape = poses.shape[:-1]
    fx = np.broadcast_to(np.eye(3), shape + (3, 3)).copy()
    fx[..., 0, 2] = -dk * s
    fx[..., 1, 2] = dk * c
    # the part of the covariance the pre-step pose does not explain (uncorrelated with it, by Stein's lemma):
    # along u: d^2 [s_d^2 E[cos^2 delta] + Var(cos delta)], across: d^2 [(1 + s_d^2) E[sin^2 delta] - k^2 P_theta]
    sd2 = cfg.drive_sigma_frac**2
    along = d**2 * (sd2 * (1.0 - a + 0.5 * a * a) + 0.5 * a * a)
    across = np.maximum(d**2 * ((1.0 + sd2) * 0.5 * a * (2.0 - a) - k2 * p_theta), 0.0)
    noise = np.zeros(shape + (3, 3))
    noise[..., 0, 0] = along * c * c + across * s * s
    noise[..., 1, 1] = along * s * s + across * c * c
    noise[..., 0, 1] = noise[..., 1, 0] = (along - across) * c * s
    noise[..., 0, 2] = noise[..., 2, 0] = -dk * turn_var * s
    noise[..., 1, 2] = noise[..., 2, 1] = dk * turn_var * c
    noise[..., 2, 2] = turn_var
    return mean, fx, noise
