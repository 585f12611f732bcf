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


INDEX_MIN = 128  # robots from which sense_swarm finds neighbours with a k-d tree (fewer: every pair, as cheap)


def neighbour_pairs(positions: np.ndarray, sensing_range: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(i, j, distance) of every ordered pair j != i with |x_j - x_i| <= ``sensing_range``, in (i, j) order, the
    distance computed as ``sense_robot`` does (the same bits). Candidates from a k-d tree from ``INDEX_MIN`` robots
    (radius widened for rounding, then the exact test), from every pair below."""
    n = len(positions)
    if n < INDEX_MIN:
        i, j = np.repeat(np.arange(n), n), np.tile(np.arange(n), n)
    else:
        from scipy.spatial import cKDTree  # noqa: PLC0415 - scipy only for large swarms (cheap agent imports)

        pairs = cKDTree(positions).query_pairs(sensing_range * (1.0 + 1e-9) + 1e-12, output_type="ndarray")
        i, j = np.concatenate([pairs[:, 0], pairs[:, 1]]), np.concatenate([pairs[:, 1], pairs[:, 0]])
        order = np.lexsort((j, i))
        i, j = i[order].astype(np.int64), j[order].astype(np.int64)
    d = positions[j] - positions[i]
    dist = np.hypot(d[:, 0], d[:, 1])
    keep = (dist <= sensing_range) & (i != j)
    return i[keep], j[keep], dist[keep]


def sense_swarm(poses: np.ndarray, ids: np.ndarray, cfg: ModelConfig, rngs: list[np.random.Generator]) -> Observations:
    """Every robot's observations, robot i drawing from ``rngs[i]`` (its own stream): the numbers of ``sense_robot``
    for each robot in turn, its neighbours found for all robots at once (``neighbour_pairs``)."""
    poses = np.asarray(poses, float)
    i, j, dist = neighbour_pairs(poses[:, :2], cfg.sensing_range_m)
    counts = np.bincount(i, minlength=len(poses))
    draws = [(rng.random(k), rng.normal(0.0, 1.0, k), rng.normal(0.0, 1.0, k)) for rng, k in zip(rngs, counts.tolist(), strict=True)]
    uniform, z_range, z_bearing = (np.concatenate([d[c] for d in draws]) if draws else np.zeros(0) for c in range(3))
    d = poses[j, :2] - poses[i, :2]
    phi = wrap_angle(np.arctan2(d[:, 1], d[:, 0]) - poses[i, 2])
    rho, phi, keep = add_sensing_noise(dist, phi, uniform, z_range, z_bearing, cfg)
    ids = np.asarray(ids)
    return Observations(ids[i[keep]], ids[j[keep]], rho[keep], phi[keep])
