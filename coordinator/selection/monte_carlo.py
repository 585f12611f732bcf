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

import functools
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


Block = tuple[int, int]  # (samples, seed): one set of common random numbers


@dataclass(frozen=True)
class MonteCarlo:
    """e_l estimator for one configuration change, with its own common random numbers."""

    cfg: ModelConfig
    localizer: Localizer  # the executor's (``registry.make_localizer``), options included
    samples: int
    seed: int
    start: str = "estimate"  # one of ``MC_STARTS``

    def localization_errors(self, estimate: SwarmEstimate, desired: np.ndarray, plans: list[Plan], per_sample: bool = False,
                            window: np.ndarray | None = None) -> np.ndarray:
        """Mean e_l (m) over the samples for each plan; (plans, samples) with ``per_sample``.

        ``window`` (n,) bool simulates only those robots (part of a large swarm): the others are
        absent, each step moves the plan's movers among them (possibly none), and e_l is the
        mean over them.
        """
        e_l = block_errors(self.cfg, self.localizer, self.start, [(self.samples, self.seed)], estimate, desired, plans, window)
        return e_l if per_sample else cast(np.ndarray, e_l.mean(axis=1))


def block_errors(cfg: ModelConfig, localizer: Localizer, start: str, blocks: list[Block], estimate: SwarmEstimate,
                 desired: np.ndarray, plans: list[Plan], window: np.ndarray | None = None) -> np.ndarray:
    """e_l (m) per plan and sample (plans, samples of every block) of ``plans`` simulated on the sample sets ``blocks``
    at once, each block's samples drawn as ``MonteCarlo(samples, seed)`` draws them, so every sample's e_l is the one
    that block alone gives. Plans may have different step counts: a plan's samples stop at its last step (the
    batched localization of a step takes the plans that have it; those for which it is the last, poses alone, apart)."""
    k_steps = np.array([p.n_steps for p in plans])
    masks = np.zeros((len(plans), int(k_steps.max()), estimate.n), bool)  # (c, k, n)
    for p, plan in enumerate(plans):
        masks[p, : plan.n_steps] = np.stack([plan.moving(k) for k in range(plan.n_steps)])
    if window is not None:
        estimate, desired, masks = estimate.select(window), desired[window], masks[..., window]
    n, c = estimate.n, len(plans)
    starts = [_start_draws(cfg, estimate, count, seed, start) for count, seed in blocks]
    truth, turn, drive = (np.concatenate(parts) for parts in zip(*starts, strict=True))
    s = len(turn)
    truth = np.broadcast_to(truth, (c, s, n, 3)).copy()
    est = np.broadcast_to(estimate.poses, (c, s, n, 3)).copy()
    cov = np.broadcast_to(estimate.cov, (c, s, n, 3, 3)).copy()
    eye = np.eye(n, dtype=bool)
    for k in range(masks.shape[1]):
        live = np.flatnonzero(k_steps > k)
        last = k_steps[live] == k + 1
        # a plan's last step is localized for its poses alone (e_l reads nothing else), in a batch of its own where
        # other plans go on: every plan's samples take the same arithmetic whatever it is simulated with
        for part, covariances in ((live[~last], True), (live[last], False)):
            if not part.size:
                continue
            every = len(part) == c
            m = len(part)
            t, e, v = (truth, est, cov) if every else (truth[part], est[part], cov[part])
            moving = np.broadcast_to(masks[part, k, None, :], (m, s, n))
            commands = np.where(moving[..., None], command_towards(e, desired), 0.0)
            t = np.where(moving[..., None], apply_motion(t, commands, turn, drive), t)
            true_rho, true_phi = measure(t[..., :, None, :], t[..., None, :, :2])  # (m, s, n, n)
            step_draws = [_step_draws(seed, count, n, k) for count, seed in blocks]
            uniform, z_range, z_bearing = (np.concatenate(parts) for parts in zip(*step_draws, strict=True))
            rho, phi, keep = add_sensing_noise(true_rho, true_phi, uniform, z_range, z_bearing, cfg)
            seen = keep & (true_rho <= cfg.sensing_range_m) & ~eye
            out = localize_batch(
                localizer, cfg,
                e.reshape(m * s, n, 3), v.reshape(m * s, n, 3, 3), commands.reshape(m * s, n, 2),
                moving.reshape(m * s, n), seen.reshape(m * s, n, n), rho.reshape(m * s, n, n), phi.reshape(m * s, n, n),
                covariances=covariances,
            )
            if every:
                truth, est, cov = t, out.poses.reshape(c, s, n, 3), out.cov.reshape(c, s, n, 3, 3)
            else:
                truth[part], est[part], cov[part] = t, out.poses.reshape(m, s, n, 3), out.cov.reshape(m, s, n, 3, 3)
    return cast(np.ndarray, np.mean(np.linalg.norm(truth[..., :2] - est[..., :2], axis=-1), axis=-1))  # Eq. 8, (c, s)


def _start_draws(cfg: ModelConfig, estimate: SwarmEstimate, samples: int, seed: int,
                 start: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(initial truths (samples, n, 3), turn and drive noise (samples, n)) of one sample set."""
    n, s = estimate.n, samples
    rng = np.random.default_rng([seed, 0])
    if estimate.joint is None:
        chol = np.linalg.cholesky(estimate.cov + 1e-15 * np.eye(3))
        truth = estimate.poses + np.einsum("nab,snb->sna", chol, rng.normal(size=(s, n, 3)))
    else:  # correlated errors: drawn from the joint covariance the localizer carries
        chol = np.linalg.cholesky(estimate.joint + 1e-15 * np.eye(3 * n))
        truth = estimate.poses + (rng.normal(size=(s, 3 * n)) @ chol.T).reshape(s, n, 3)
    if start == "known":  # the draws above are still made: the noise streams below stay common
        truth = np.broadcast_to(estimate.poses, (s, n, 3))
    turn, drive = draw_motion_noise(rng, (s, n), cfg)
    return truth, turn, drive


KEPT_DRAWS = 1 << 16  # sensing draws of at most this many elements (samples x n x n, 1.5 MB) are kept, 16 sets at most


def _step_draws(seed: int, samples: int, n: int, step: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The standard draws (uniform, normal, normal) (samples, n, n) of one sample set's sensing in ``step``, read-only;
    small sets are kept (a selection's genetic search draws its samples' sensing again at every generation)."""
    if samples * n * n <= KEPT_DRAWS:
        return _kept_step_draws(seed, samples, n, step)
    return _new_step_draws(seed, samples, n, step)


def _new_step_draws(seed: int, samples: int, n: int, step: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng([seed, 1, step])
    draws = rng.random((samples, n, n)), rng.normal(size=(samples, n, n)), rng.normal(size=(samples, n, n))
    for a in draws:
        a.flags.writeable = False
    return draws


_kept_step_draws = functools.lru_cache(maxsize=16)(_new_step_draws)  # 25 MB at most


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
