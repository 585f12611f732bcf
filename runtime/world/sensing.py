"""What a robot of the physical world sees: range/bearing of the bodies in range, in view and not hidden.

Robot i sees robot j when their centres are at most the sensing range apart, j's bearing lies
within the field of view (centred on i's heading), and no third body k covers the line of sight:
the segment between the centres passes closer than k's radius to k's centre (k strictly between
them). The measurement of a sighting adds N(0, range_sigma_m + range_sigma_frac d) to the range d
and N(0, bearing_sigma_rad) to the bearing; each is lost with the dropout probability. numpy over
every target and blocker of one observer.
"""

from __future__ import annotations

from typing import cast

import numpy as np

from runtime.models.geometry import wrap_angle
from runtime.world.params import PhysicsParams


def visible(poses: np.ndarray, index: int, params: PhysicsParams) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(indices of the robots ``index`` sees, ascending; their true ranges m; true bearings rad in its body frame)."""
    centres = poses[:, :2]
    d = centres - centres[index]
    dist = np.hypot(d[:, 0], d[:, 1])
    bearing = wrap_angle(np.arctan2(d[:, 1], d[:, 0]) - poses[index, 2])
    seen = dist <= params.sensing_range_m
    seen[index] = False
    if params.fov_rad < 2.0 * np.pi:
        seen &= np.abs(bearing) <= params.fov_rad / 2.0
    targets = np.flatnonzero(seen)
    if params.occlusion and len(targets) and len(poses) > 2:
        targets = targets[~_occluded(centres, index, targets, params.radius_m)]
    return targets, dist[targets], bearing[targets]


def _occluded(centres: np.ndarray, index: int, targets: np.ndarray, radius: float) -> np.ndarray:
    """Per target: whether a third body's disc crosses the segment from ``index``'s centre to the target's."""
    origin = centres[index]
    seg = centres[targets] - origin  # (t, 2)
    rel = centres - origin  # (n, 2) blockers
    length2 = np.einsum("ij,ij->i", seg, seg)
    s = (rel @ seg.T) / np.where(length2 > 0, length2, 1.0)  # (n, t) projection parameter along each segment
    between = (s > 0.0) & (s < 1.0)
    closest = rel[:, None, :] - s[:, :, None] * seg[None, :, :]
    near = np.einsum("ntk,ntk->nt", closest, closest) < radius * radius
    blocker = between & near
    blocker[index, :] = False
    blocker[targets, np.arange(len(targets))] = False
    return cast(np.ndarray, blocker.any(axis=0))


def sense(poses: np.ndarray, index: int, params: PhysicsParams, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Robot ``index``'s noisy sightings (indices, ranges m, bearings rad) drawing from ``rng``: for the k robots it sees,
    k dropout uniforms, then k range normals, then k bearing normals (as ``runtime.models.sensing.sense_robot``)."""
    idx, rho, phi = visible(poses, index, params)
    k = len(idx)
    uniform, z_range, z_bearing = rng.random(k), rng.normal(0.0, 1.0, k), rng.normal(0.0, 1.0, k)
    keep = uniform >= params.dropout_prob
    noisy = np.maximum(rho + z_range * (params.range_sigma_m + params.range_sigma_frac * rho), 0.0)
    return idx[keep], noisy[keep], wrap_angle(phi + z_bearing * params.bearing_sigma_rad)[keep]
