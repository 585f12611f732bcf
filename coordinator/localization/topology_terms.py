"""Eq. B1-B3's observation terms, elementwise over arrays of any common shape: the offset z_ij, the residual, its
heading derivative and curvature. One definition for one swarm's topology (``topology``), its large-swarm normal
equations (``topology_normal``) and the planner's batch (``batch``)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import cast

import numpy as np


def observation_offsets(range_m: np.ndarray, bearing_rad: np.ndarray) -> np.ndarray:
    """Eq. B1: z_ij = (rho cos phi, rho sin phi) in the observer's body frame."""
    return np.stack([range_m * np.cos(bearing_rad), range_m * np.sin(bearing_rad)], axis=-1)


def observation_residuals(
    cos_i: np.ndarray,
    sin_i: np.ndarray,
    zx: np.ndarray,
    zy: np.ndarray,
    xi: np.ndarray,
    yi: np.ndarray,
    xj: np.ndarray,
    yj: np.ndarray,
    out: Sequence[np.ndarray] | None = None,
    scratch: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Eq. B3's residual of observations i -> j, elementwise over arrays of any (common) shape: the one
    definition for one swarm (``estimate_topology``) and for the planner's batch (``batch``).

    ``cos_i``, ``sin_i``: of the observer's heading theta_i; ``zx``, ``zy``: the offset z_ij (Eq. B1);
    ``xi``, ``yi``, ``xj``, ``yj``: the two positions (m). Returns (R(theta_i) z_ij (two arrays), the residual
    R(theta_i) z_ij + x_i - x_j (two arrays)); d r / d theta_i = (-(R z)_y, (R z)_x), d r / d x_i = I,
    d r / d x_j = -I, d^2 r / d theta_i^2 = -R z. ``out``: four arrays to write them into, ``scratch`` one more.
    """
    o = (None, None, None, None) if out is None else out  # outputs positional: faster than ``out=`` keywords
    rzx = np.multiply(cos_i, zx, o[0])
    rzx -= np.multiply(sin_i, zy, scratch)
    rzy = np.multiply(sin_i, zx, o[1])
    rzy += np.multiply(cos_i, zy, scratch)
    rx = np.add(rzx, xi, o[2])  # Eq. B4 minus x_j
    rx -= xj
    ry = np.add(rzy, yi, o[3])
    ry -= yj
    return rzx, rzy, rx, ry


def observation_jacobian(rzx: np.ndarray, rzy: np.ndarray, out: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """d r_ij / d theta_i = (-(R z)_y, (R z)_x) of Eq. B3's residual, elementwise from ``observation_residuals``'
    R(theta_i) z_ij: the one definition for one swarm's sparse Jacobian and the batch's J^T J (d r / d x_i = I and
    d r / d x_j = -I). ``out``: an array for the first component (the second is ``rzx`` itself)."""
    return np.negative(rzy, out), rzx


def heading_curvature(rzx: np.ndarray, rzy: np.ndarray, rx: np.ndarray, ry: np.ndarray) -> np.ndarray:
    """r . d^2 r / d theta_i^2 = -r . R(theta_i) z_ij of each observation, elementwise: the second-order term of the
    observer's heading that Gauss-Newton drops (``sparse_lm``'s curvature)."""
    return cast(np.ndarray, -(rx * rzx + ry * rzy))
