"""Expected localization error e_l of candidate plans by Monte Carlo simulation (Eq. 8, 9).

Every candidate plan is simulated through all of its steps with the shared motion and
sensing models and the executor's localizer object (with its options), vectorised over
candidates x samples (``localize_batch``). Candidates are compared on common random numbers: the same draws
of the initial-estimate error, of each robot's motion noise (every robot moves once per
configuration change) and of each step's sensing noise, so differences in e_l come from
the plans, not from the luck of the draw.

Where the simulated configuration change starts (``start``, ``docs/experiments.md``):
``"estimate"`` draws the initial truths from N(estimate, its covariance), so e_l includes the
error accumulated before this change; ``"known"`` starts every sample at the estimate's mean
(Sec. 4.2: "assuming knowledge of the swarm's initial configuration"), so e_l scores the error
this change adds. The simulated localizer's prior is the estimate and its covariance in both;
the initial-error draws are made either way, so the motion and sensing draws are the same.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import cast

import numpy as np

from coordinator.localization import Localizer
from coordinator.localization.batch import localize_batch
from coordinator.plan import Plan
from runtime.models.config import ModelConfig
from runtime.models.motion import apply_motion, command_towards, draw_motion_noise
from runtime.models.sensing import add_sensing_noise, measure
from runtime.models.state import SwarmEstimate
from runtime.models.trajectory import is_connected

MC_STARTS = ("estimate", "known")  # initial truths: drawn from the estimate's covariance, or at its mean


@dataclass(frozen=True)
class MonteCarlo:
    """e_l estimator for one configuration change, with its own common random numbers."""

    cfg: ModelConfig
    localizer: Localizer  # the executor's (``registry.make_localizer``), options included
    samples: int
    seed: int
    start: str = "estimate"  # one of ``MC_STARTS``

    def _step_rng(self, step: int) -> np.random.Generator:
        return np.random.default_rng([self.seed, 1, step])

    def localization_errors(self, estimate: SwarmEstimate, desired: np.ndarray, plans: list[Plan], per_sample: bool = False,
                            window: np.ndarray | None = None) -> np.ndarray:
        """Mean e_l (m) over the samples for each plan (all plans must have the same step count); (plans, samples) with ``per_sample``.

        ``window`` (n,) bool simulates only those robots (part of a large swarm): the others are
        absent, each step moves the plan's movers among them (possibly none), and e_l is the
        mean over them.
        """
        k_steps = plans[0].n_steps
        masks = np.stack([np.stack([p.moving(k) for k in range(k_steps)]) for p in plans])  # (c, k, n)
        if window is not None:
            estimate, desired, masks = estimate.select(window), desired[window], masks[..., window]
        n, s, c = estimate.n, self.samples, len(plans)
        rng = np.random.default_rng([self.seed, 0])
        if estimate.joint is None:
            chol = np.linalg.cholesky(estimate.cov + 1e-15 * np.eye(3))
            truth = estimate.poses + np.einsum("nab,snb->sna", chol, rng.normal(size=(s, n, 3)))
        else:  # correlated errors: drawn from the joint covariance the localizer carries
            chol = np.linalg.cholesky(estimate.joint + 1e-15 * np.eye(3 * n))
            truth = estimate.poses + (rng.normal(size=(s, 3 * n)) @ chol.T).reshape(s, n, 3)
        if self.start == "known":  # the draws above are still made: the noise streams below stay common
            truth = np.broadcast_to(estimate.poses, (s, n, 3))
        turn, drive = draw_motion_noise(rng, (s, n), self.cfg)
        truth = np.broadcast_to(truth, (c, s, n, 3)).copy()
        est = np.broadcast_to(estimate.poses, (c, s, n, 3)).copy()
        cov = np.broadcast_to(estimate.cov, (c, s, n, 3, 3)).copy()
        eye = np.eye(n, dtype=bool)
        for k in range(k_steps):
            moving = np.broadcast_to(masks[:, k, None, :], (c, s, n))
            commands = np.where(moving[..., None], command_towards(est, desired), 0.0)
            truth = np.where(moving[..., None], apply_motion(truth, commands, turn, drive), truth)
            true_rho, true_phi = measure(truth[..., :, None, :], truth[..., None, :, :2])  # (c, s, n, n)
            step_rng = self._step_rng(k)
            draws = (step_rng.random((s, n, n)), step_rng.normal(size=(s, n, n)), step_rng.normal(size=(s, n, n)))
            rho, phi, keep = add_sensing_noise(true_rho, true_phi, *draws, self.cfg)
            seen = keep & (true_rho <= self.cfg.sensing_range_m) & ~eye
            out = localize_batch(
                self.localizer, self.cfg,
                est.reshape(c * s, n, 3), cov.reshape(c * s, n, 3, 3), commands.reshape(c * s, n, 2),
                moving.reshape(c * s, n), seen.reshape(c * s, n, n), rho.reshape(c * s, n, n), phi.reshape(c * s, n, n),
            )
            est = out.poses.reshape(c, s, n, 3)
            cov = out.cov.reshape(c, s, n, 3, 3)
        e_l = np.mean(np.linalg.norm(truth[..., :2] - est[..., :2], axis=-1), axis=-1)  # Eq. 8, (c, s)
        return cast(np.ndarray, e_l if per_sample else e_l.mean(axis=1))


def plan_keeps_connectivity(plan: Plan, current: np.ndarray, desired: np.ndarray, sensing_range: float,
                            known: dict[bytes, bool] | None = None) -> bool:
    """Constraint g (Eq. 4): after every step the expected configuration is connected within sensing range.

    ``known``: configurations already checked (by their bytes; the caller's, for one ``current`` -> ``desired``
    change): the plans of a selection share most of their steps' configurations.
    """
    positions = np.array(current, dtype=float)
    known = {} if known is None else known
    for group in plan.groups:
        positions[group] = desired[group]
        key = positions.tobytes()
        if key not in known:
            known[key] = is_connected(positions, sensing_range)
        if not known[key]:
            return False
    return True
