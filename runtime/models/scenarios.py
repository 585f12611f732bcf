"""Synthetic swarms and single localization steps, for tests, benchmarks and studies.

A step case follows the generative model the localizers assume: the pre-step true
poses differ from the estimate by a draw from the estimate's covariance, the mobile
robots execute their commands with motion noise, and every robot observes its
neighbours with sensing noise (all from explicit generators).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from runtime.models.config import ModelConfig
from runtime.models.motion import apply_motion, command_towards, draw_motion_noise
from runtime.models.rng import Stream, robot_rngs
from runtime.models.sensing import sense_swarm
from runtime.models.state import Observations, StepCommands, SwarmEstimate


def grid_configuration(n: int, spacing: float, rng: np.random.Generator, jitter: float = 0.25) -> np.ndarray:
    """Poses (n, 3): a near-square grid with ``spacing`` (m), jittered by ``jitter`` x spacing, random headings."""
    cols = math.ceil(math.sqrt(n))
    k = np.arange(n)
    xy = np.column_stack([k % cols, k // cols]) * spacing
    xy = xy + rng.uniform(-jitter, jitter, (n, 2)) * spacing
    return np.column_stack([xy, rng.uniform(-np.pi, np.pi, n)])


@dataclass(frozen=True)
class StepCase:
    """One inchworm step with its ground truth."""

    prior: SwarmEstimate
    step: StepCommands
    observations: Observations
    true_before: np.ndarray  # (n, 3)
    true_after: np.ndarray  # (n, 3)


def random_step(
    n: int,
    cfg: ModelConfig,
    rng: np.random.Generator,
    *,
    spacing: float = 0.2,
    prior_delta: float = 0.02,
    prior_heading_sigma: float = math.radians(2.0),
    mobile_fraction: float = 0.5,
    move: float = 0.15,
    seed: int = 0,
    still_delta: float | None = None,
) -> StepCase:
    """A step of ``n`` robots on a jittered grid; a random ``mobile_fraction`` moves ~``move`` m.

    ``rng`` draws the layout, prior error, mobile set and motion noise; sensing uses
    the per-robot streams of ``seed``. ``still_delta`` (m): the prior position std of the
    robots that do not move (anchors), if not ``prior_delta``; the draws are the same either way.
    """
    ids = np.arange(n)
    estimate = grid_configuration(n, spacing, rng)
    unit = rng.normal(size=(n, 3))
    moving = np.zeros(n, bool)
    moving[rng.choice(n, max(1, round(mobile_fraction * n)), replace=False)] = True
    delta = np.where(moving, prior_delta, prior_delta if still_delta is None else still_delta)
    prior = SwarmEstimate.isotropic(ids, estimate, delta, prior_heading_sigma)
    true_before = estimate + np.einsum("nab,nb->na", np.linalg.cholesky(prior.cov + 1e-15 * np.eye(3)), unit)
    angle = rng.uniform(-np.pi, np.pi)
    targets = estimate[:, :2] + move * np.array([math.cos(angle), math.sin(angle)]) + rng.normal(0, 0.2 * move, (n, 2))
    commands = np.where(moving[:, None], command_towards(estimate, targets), 0.0)
    turn, drive = draw_motion_noise(rng, (n,), cfg)
    true_after = np.where(moving[:, None], apply_motion(true_before, commands, turn, drive), true_before)
    observations = sense_swarm(true_after, ids, cfg, robot_rngs(seed, ids, Stream.SENSING))
    return StepCase(prior, StepCommands(ids, commands, moving), observations, true_before, true_after)
