"""Planar geometry helpers, vectorised over any leading batch shape (radians, metres)."""

from __future__ import annotations

import numpy as np


def wrap_angle(angle: np.ndarray | float) -> np.ndarray:
    """Wrap angles to [-pi, pi)."""
    return (np.asarray(angle) + np.pi) % (2.0 * np.pi) - np.pi


def rotate(theta: np.ndarray | float, xy: np.ndarray) -> np.ndarray:
    """Rotate 2D vectors ``xy`` (..., 2) by angles ``theta`` (...) (Eq. 16)."""
    c, s = np.cos(theta), np.sin(theta)
    x, y = xy[..., 0], xy[..., 1]
    return np.stack([c * x - s * y, s * x + c * y], axis=-1)


def transform_poses(poses: np.ndarray, theta: float, t: np.ndarray) -> np.ndarray:
    """Apply the rigid motion (rotation ``theta``, translation ``t``) to poses (..., 3)."""
    out = np.empty_like(poses, dtype=float)
    out[..., :2] = rotate(theta, poses[..., :2]) + t
    out[..., 2] = wrap_angle(poses[..., 2] + theta)
    return out
