"""A large swarm's step localized around its movers (the paper's localizer from ``LOCAL_MIN`` robots).

A body-regrouped step of 10,000 robots often moves a few dozen of them; the others stood still, and their dead
reckoning is their prior. Solving Eq. B3 for every robot again (``topology.estimate_topology``: a sparse Cholesky of
30,000 unknowns, ~n^1.8) is then most of the step. Here the least squares is solved for the *region* alone: the
movers and the robots within ``RING_HOPS`` observation hops of them (observations taken in both directions), over
every observation a region robot made or received, with the robots one hop further (the *boundary*) held at their
priors. The boundary fixes the gauge, so the topology comes out in the global frame. Every other robot is turned by
the weighted circular mean of its bearings' misfit to the robots it saw (``topology.heading_turn``: Eq. B3 for its
heading alone, the positions held), and then every robot's cluster (Eq. B4-B6) is formed from all the step's
observations, each placed by its observer's pose: the region's solved, the others' priors so turned. The clusters are
superimposed (Eq. 21-22) onto the still robots' dead reckoning, their priors, and fused with it (Eq. 23) as the whole
swarm's topology is. The superimposition is nearly the identity, but not to be skipped: the clusters of the robots
outside the region carry the step's observation noise, and its mean over the swarm moves the swarm's common
translation and rotation a little every step, which nothing pulls back (a random walk: without it, 70-robot swarms
with one mover a step drifted to 1.5-2 x the whole solve's mean position error in 100 steps, docs/localization.md).
Relative observations say nothing of that common pose, so it is taken from the still robots' priors alone; the whole
swarm's Eq. 22 weights the movers' dead reckoning in as well, and with it their motion noise.

The answer is not the whole swarm's solve: a still robot outside the region is placed by its neighbours' priors, not
by a solve of everyone, and the boundary carries its priors' errors. Against the whole swarm's solve of the same
steps of 2048-10,000 robots (docs/localization.md, "Speed"): the movers within 0.17 of their own sigma, everyone's
positions 0.05-0.07 sigma at the median, headings 0.11-0.16; at the end of a run P_f the same within 0.0003, the
mean position error -1 to +15 % of the whole solve's; over 8-20 configurations of 500-2048 robots, 0.93-1.11 x the
whole solve's at every configuration (docs/benchmarks.md).
``PaperLocalizer`` asks for it from ``LOCAL_MIN`` robots (below, the results the tests pin stay bit for bit);
``region_topology`` returns None, and the whole swarm is solved, when nobody moved (a stationary step localizes from
scratch, e.g. a rejoin), when the region holds more than ``LOCAL_MAX_FRACTION`` of the swarm, or when the region's
least squares does not converge.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from coordinator.localization.sparse_lm import PoseLayout
from coordinator.localization.topology import LARGE_MIN, clusters, heading_turn, solve_by_jacobian
from coordinator.localization.topology_terms import observation_offsets
from runtime.models.config import ModelConfig
from runtime.models.geometry import wrap_angle

LOCAL_MIN = LARGE_MIN  # robots from which a step is localized around its movers
RING_HOPS = 1  # observation hops around the movers solved with them
LOCAL_MAX_FRACTION = 0.25  # largest share of the swarm in the region; more: the whole swarm is solved


@dataclass(frozen=True)
class GlobalTopology:
    """A topology in the global frame (``Topology``'s fields, no reference robot)."""

    positions: np.ndarray  # (n, 2) cluster centroids (m)
    headings: np.ndarray  # (n,) (rad), NaN for robots observing nobody
    delta_p: np.ndarray  # (n,) Eq. B6 (m)
    heading_sigma: np.ndarray  # (n,) (rad), inf for robots observing nobody
    region: np.ndarray  # (n,) the robots whose poses were solved for


def hops_from(seed: np.ndarray, observer: np.ndarray, observed: np.ndarray, hops: int) -> np.ndarray:
    """Observation hops (n,) of every robot from the robots where ``seed`` (n,) (0 there), -1 beyond ``hops``;
    observations (robot indices) taken in both directions."""
    hop = np.where(seed, 0, -1)
    frontier = seed.copy()
    for h in range(1, hops + 1):
        near = np.zeros(len(seed), bool)
        near[observed[frontier[observer]]] = True
        near[observer[frontier[observed]]] = True
        frontier = near & (hop < 0)
        hop[frontier] = h
    return hop


def region_topology(
    prior_poses: np.ndarray, moving: np.ndarray, observer: np.ndarray, observed: np.ndarray, range_m: np.ndarray,
    bearing_rad: np.ndarray, cfg: ModelConfig, huber: float | None = None,
) -> GlobalTopology | None:
    """The topology of the step from the movers' region (the module docstring), or None when the whole swarm is to be
    solved.

    ``prior_poses`` (n, 3): the step's dead reckoning (Phase 1.1; the still robots' priors), ``moving`` (n,) the
    robots that moved, ``observer``/``observed`` the observations' robot indices with their ``range_m`` and
    ``bearing_rad``; ``huber`` as ``estimate_topology``'s. The caller decides from what size (``LOCAL_MIN``).
    """
    n = len(prior_poses)
    if not moving.any():
        return None
    hop = hops_from(moving, observer, observed, RING_HOPS + 1)
    region, boundary = (hop >= 0) & (hop <= RING_HOPS), hop == RING_HOPS + 1
    if region.sum() > LOCAL_MAX_FRACTION * n or not boundary.any():
        return None
    inside = region | boundary
    live = region[observer] & inside[observed] | region[observed] & inside[observer]  # every observation of the region
    rows = np.flatnonzero(inside)
    local = np.full(n, -1)
    local[rows] = np.arange(len(rows))
    i, j = local[observer[live]], local[observed[live]]
    free = region[rows]
    layout = PoseLayout(free, free & (np.bincount(i, minlength=len(rows)) > 0))
    start = prior_poses[rows]
    result = solve_by_jacobian(layout, start, i, j, observation_offsets(range_m[live], bearing_rad[live]), huber)
    if not result.converged:
        return None
    poses = np.array(prior_poses, dtype=float)
    poses[region] = layout.unpack(result.x, start)[free]
    others = ~region
    poses[others, 2] += heading_turn(poses, observer, observed, bearing_rad, range_m)[others]
    poses[:, 2] = wrap_angle(poses[:, 2])
    z = observation_offsets(range_m, bearing_rad)
    centroid, delta_p, heading_sigma = clusters(poses, observer, observed, z, range_m, cfg, huber)
    headings = np.where(np.bincount(observer, minlength=n) > 0, poses[:, 2], np.nan)
    return GlobalTopology(centroid, headings, delta_p, heading_sigma, region)


__all__ = ["LOCAL_MAX_FRACTION", "LOCAL_MIN", "RING_HOPS", "GlobalTopology", "hops_from", "region_topology"]
