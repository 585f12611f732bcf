"""Phase 2: weighted 2D rigid superimposition of topology onto configuration (Eq. 21-22).

Finds the pose (t, theta) of the local frame in the global frame minimising
sum_i w_i |R(theta) p_i + t - q_i|^2 (Eq. 21) in closed form (weighted Procrustes /
Kabsch without scale): with weighted centroids p_c, q_c and centred points P, Q,
theta = atan2(sum w (P x Q), sum w (P . Q)) and t = q_c - R(theta) p_c.
Vectorised over leading batch dimensions.
"""

from __future__ import annotations

from typing import cast

import numpy as np

from runtime.errors import LocalizationError
from runtime.models.geometry import rotate

MIN_SPREAD = 1e-12  # m^2: below this weighted spread the rotation is undetermined


def fusion_weights(delta_p: np.ndarray, delta_u: np.ndarray) -> np.ndarray:
    """Eq. 22: w_i = 1 / (delta_pi + delta_ui), with the sum floored at 1e-9 m (noise-free inputs)."""
    return cast(np.ndarray, 1.0 / np.maximum(delta_p + delta_u, 1e-9))


def superimpose(p: np.ndarray, q: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation theta (...,) and translation t (..., 2) that best map points p onto q (..., n, 2)."""
    w = np.asarray(w, dtype=float)
    if np.any(~np.isfinite(w)) or np.any(w <= 0):
        raise LocalizationError("degenerate", [], "superimposition weights must be finite and > 0")
    theta, t, spread = weighted_procrustes(p, q, w)
    if np.any(spread <= MIN_SPREAD):
        raise LocalizationError("degenerate", [], "all topology points coincide: rotation is undetermined")
    return theta, t


def weighted_procrustes(p: np.ndarray, q: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``superimpose`` without the checks: (theta, t, weighted spread of p in m^2), vectorised.

    The rotation is meaningless where the spread is <= ``MIN_SPREAD``; the caller decides.
    """
    wn = w / w.sum(axis=-1, keepdims=True)
    pc = np.einsum("...i,...ik->...k", wn, p)
    qc = np.einsum("...i,...ik->...k", wn, q)
    pp, qq = p - pc[..., None, :], q - qc[..., None, :]
    dot = np.einsum("...i,...i->...", wn, pp[..., 0] * qq[..., 0] + pp[..., 1] * qq[..., 1])
    cross = np.einsum("...i,...i->...", wn, pp[..., 0] * qq[..., 1] - pp[..., 1] * qq[..., 0])
    spread = np.einsum("...i,...i->...", wn, np.sum(pp**2, axis=-1))
    theta = np.arctan2(cross, dot)
    t = qc - rotate(theta, pc)
    return theta, t, spread
