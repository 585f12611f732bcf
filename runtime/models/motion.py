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
    return fx @ prior_cov @ np.swapaxes(fx, -1, -2) + fu @ q @ np.swapaxes(fu, -1, -2)
