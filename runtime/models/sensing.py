"""Range/bearing sensing model (Eq. 20, Appendix B).

Robot i observes robot j when |x_j - x_i| <= sensing range; the observation is the
range plus N(0, sigma_range) and the bearing of j in i's body frame plus
N(0, sigma_bearing), wrapped to [-pi, pi); each observation is lost with the dropout
probability. ``measure`` is deterministic and broadcasts over batches; ``sense_robot``
draws one robot's observations from that robot's own generator, so one agent process
and the in-process simulator produce identical numbers for the same seed.
"""

from __future__ import annotations

import numpy as np

from runtime.models.config import ModelConfig
from runtime.models.geometry import wrap_angle
from runtime.models.state import Observations


def measure(observer_poses: np.ndarray, target_positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Noise-free (range m, bearing rad) of targets (..., 2) seen from poses (..., 3)."""
    d = target_positions - observer_poses[..., :2]
    rng = np.hypot(d[..., 0], d[..., 1])
    brg = wrap_angle(np.arctan2(d[..., 1], d[..., 0]) - observer_poses[..., 2])
    return rng, brg


def neighbours(positions: np.ndarray, index: int, sensing_range: float) -> np.ndarray:
    """Indices j != index (ascending) within ``sensing_range`` of robot ``index``."""
    d = np.hypot(*(positions - positions[index]).T)
    mask = d <= sensing_range
    mask[index] = False
    return np.flatnonzero(mask)


def add_sensing_noise(
    rho: np.ndarray, phi: np.ndarray, uniform: np.ndarray, z_range: np.ndarray, z_bearing: np.ndarray, cfg: ModelConfig
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Noisy (range, bearing, kept) from noise-free ones and standard draws (uniform, normal, normal).

    Ranges are clipped at 0 (a range sensor reports no negative distance); bearings wrap.
    """
    keep = uniform >= cfg.dropout_prob
    noisy_rho = np.maximum(rho + z_range * cfg.range_sigma_m, 0.0)
    return noisy_rho, wrap_angle(phi + z_bearing * cfg.bearing_sigma_rad), keep


def noisy_observations(
    observer_poses: np.ndarray, target_positions: np.ndarray, cfg: ModelConfig, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(range, bearing, kept) for k targets, drawing exactly 3k numbers from ``rng``.

    Draw order per call: k dropout uniforms, k range normals, k bearing normals,
    so the stream consumption does not depend on the dropout probability.
    """
    k: int = target_positions.shape[0]
    uniform = rng.random(k)
    z_range = rng.normal(0.0, 1.0, k)
    z_bearing = rng.normal(0.0, 1.0, k)
    rho, phi = measure(observer_poses, target_positions)
    return add_sensing_noise(rho, phi, uniform, z_range, z_bearing, cfg)


def sense_robot(
    poses: np.ndarray, index: int, cfg: ModelConfig, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Robot ``index``'s observations of its neighbours given all true poses (n, 3).

    Returns (neighbour indices, ranges m, bearings rad) after dropout.
    """
    nb = neighbours(poses[:, :2], index, cfg.sensing_range_m)
    rho, phi, keep = noisy_observations(poses[index], poses[nb, :2], cfg, rng)
    return nb[keep], rho[keep], phi[keep]


def sense_swarm(poses: np.ndarray, ids: np.ndarray, cfg: ModelConfig, rngs: list[np.random.Generator]) -> Observations:
    """Every robot's observations, robot i drawing from ``rngs[i]`` (its own stream)."""
    observer, observed, ranges, bearings = [], [], [], []
    for i, rng in enumerate(rngs):
        nb, rho, phi = sense_robot(poses, i, cfg, rng)
        observer.append(np.full(len(nb), ids[i]))
        observed.append(ids[nb])
        ranges.append(rho)
        bearings.append(phi)
    return Observations(np.concatenate(observer), np.concatenate(observed), np.concatenate(ranges), np.concatenate(bearings))
