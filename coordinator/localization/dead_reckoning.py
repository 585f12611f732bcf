"""Phase 1.1: preliminary configuration estimate from the motion commands (Eq. 17-19).

With no odometry, the post-step estimate of robot i is its pre-step estimate moved by
the command it was given, executed without error: for mobile robots this is
hat u_i = x_di - hat x_t0i (Eq. 17), for anchors hat u_i = 0 (Eq. 18), and
hat x_tui = hat x_t0i + hat u_i (Eq. 19). Body-frame commands are replayed on the
estimated pose, which equals Eq. 17 when the commands were computed from that estimate.

Its uncertainty delta_u (Section 5.1.1) propagates the prior covariance and the
motion noise to first order (``runtime.models.motion.motion_covariance``). Anchors keep
their prior uncertainty: delta_u(anchor) = prior delta (the paper leaves this open).
When the prior carries the joint covariance of the swarm, it is propagated too:
P' = F P F^T + blockdiag(Fu_i Q Fu_i^T), F = blockdiag(Fx_i) (each robot moves on its own).
"""

from __future__ import annotations

from typing import cast

import numpy as np

from runtime.errors import SwarmInputError
from runtime.models.config import ModelConfig
from runtime.models.motion import apply_motion, motion_covariance, motion_moments
from runtime.models.state import StepCommands, SwarmEstimate


def exact_moments(localizer: object) -> bool:
    """Whether ``localizer`` dead-reckons with the exact moments of the motion (its ``exact_motion``; the joint
    localizer) rather than to first order (the paper's Phase 1.1, and any localizer without the attribute)."""
    return bool(getattr(localizer, "exact_motion", False))


def dead_reckon(prior: SwarmEstimate, step: StepCommands, cfg: ModelConfig, exact: bool = False) -> SwarmEstimate:
    """Post-step estimate hat C_tu with covariance, from the pre-step estimate and the commands."""
    poses, cov, joint = dead_reckon_parts(prior, step, cfg, exact)
    return SwarmEstimate(prior.ids, poses, cov, joint)


def dead_reckon_parts(
    prior: SwarmEstimate, step: StepCommands, cfg: ModelConfig, exact: bool = False
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """``dead_reckon`` as arrays: poses (n, 3), covariances (n, 3, 3), joint covariance (3n, 3n) or None."""
    if not np.array_equal(prior.ids, step.ids):
        raise SwarmInputError(
            f"step commands are for robots {step.ids.tolist()}, the estimate for {prior.ids.tolist()}"
        )
    poses, cov = dead_reckon_arrays(prior.poses, prior.cov, step.commands, step.moving, cfg, exact)
    return poses, cov, None if prior.joint is None else propagate_joint(prior, step, cfg, exact)


def propagate_joint(prior: SwarmEstimate, step: StepCommands, cfg: ModelConfig, exact: bool = False) -> np.ndarray:
    """The joint covariance (3n, 3n) after ``step``: F P F^T + motion noise (block-diagonal).

    ``exact``: F is the expected Jacobian and the noise the rest of the exact covariance (``motion_moments``).
    """
    assert prior.joint is not None, "propagates a joint covariance"
    n = prior.n
    commands = np.where(step.moving[:, None], step.commands, 0.0)
    if exact:
        _, fx, noise = motion_moments(prior.poses, prior.cov, commands, cfg)
    else:
        noise = np.where(step.moving[:, None, None], motion_covariance(prior.poses, np.zeros((n, 3, 3)), commands, cfg), 0.0)
        heading = prior.poses[:, 2] + commands[:, 0]
        fx = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
        fx[:, 0, 2] = -commands[:, 1] * np.sin(heading)
        fx[:, 1, 2] = commands[:, 1] * np.cos(heading)
    p = prior.joint.reshape(n, 3, n, 3)
    out = np.einsum("iab,ibjc,jdc->iajd", fx, p, fx, optimize=True)
    out[np.arange(n), :, np.arange(n), :] += noise
    out = out.reshape(3 * n, 3 * n)
    return cast(np.ndarray, 0.5 * (out + out.T))


def dead_reckon_arrays(
    poses: np.ndarray, cov: np.ndarray, commands: np.ndarray, moving: np.ndarray, cfg: ModelConfig, exact: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """Dead-reckoning poses (..., n, 3) and covariances (..., n, 3, 3), with the same leading batch axes on every argument.

    ``commands`` (..., n, 2) of robots that are not ``moving`` (..., n) are ignored, as in ``StepCommands``.
    """
    moved = np.nonzero(moving)  # the others keep their pose and covariance: computed for the movers only
    out, out_cov = np.array(poses, dtype=float), np.array(cov, dtype=float)
    if exact:
        mean, fx, noise = motion_moments(poses[moved], cov[moved], commands[moved], cfg)
        out[moved] = mean
        out_cov[moved] = fx @ cov[moved] @ np.swapaxes(fx, -1, -2) + noise
    else:
        out[moved] = apply_motion(poses[moved], commands[moved])
        out_cov[moved] = motion_covariance(poses[moved], cov[moved], commands[moved], cfg)
    return out, out_cov
