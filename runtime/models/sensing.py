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


def add_sensing_noise(
    rho: np.ndarray, phi: np.ndarray, uniform: np.ndarray, z_range: np.ndarray, z_bearing: np.ndarray, cfg: ModelConfig
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Noisy (range, bearing, kept) from noise-free ones and standard draws (uniform, normal, normal).

    Ranges are clipped at 0 (a range sensor reports no negative distance); bearings wrap.
    """
    keep = uniform >= cfg.dropout_prob
    noisy_rho = np.maximum(rho + z_range * cfg.range_sigma_m, 0.0)
    return noisy_rho, wrap_angle(phi + z_bearing * cfg.bearing_sigma_rad), keep


def sense_robot(
    poses: np.ndarray, index: int, cfg: ModelConfig, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Robot ``index``'s observations of its neighbours given all true poses (n, 3).

    Returns (neighbour indices, ranges m, bearings rad) after dropout. Neighbours are the robots j != index
    within the sensing range, ascending; for k of them ``rng`` gives k dropout uniforms, then k range normals,
    then k bearing normals, so the stream's use does not depend on the dropout probability.
    """
    d = poses[:, :2] - poses[index, :2]
    dist = np.hypot(d[:, 0], d[:, 1])
    mask = dist <= cfg.sensing_range_m
    mask[index] = False
    nb = np.flatnonzero(mask)
    k = len(nb)
    uniform, z_range, z_bearing = rng.random(k), rng.normal(0.0, 1.0, k), rng.normal(0.0, 1.0, k)  # the order above
    phi = wrap_angle(np.arctan2(d[nb, 1], d[nb, 0]) - poses[index, 2])
    rho, phi, keep = add_sensing_noise(dist[nb], phi, uniform, z_range, z_bearing, cfg)
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
