"""The paper's two-phase swarm localization (Section 5, Fig. 8).

Phase 1.1 dead reckoning (Eq. 17-19) and Phase 1.2 topology estimation (Eq. 20,
B1-B6) are computed independently, then Phase 2 superimposes the topology onto the
dead-reckoning configuration with weights w_i = 1 / (delta_pi + delta_ui) (Eq. 21-22)
and takes the midpoint of the two (Eq. 23).

Decisions the paper leaves open (docs/localization.md):
* Headings: the topology orientation of robot i rotated into the global frame, and
  the dead-reckoning heading, are averaged like Eq. 23 (circular midpoint); a robot
  that observes nobody keeps its dead-reckoning heading.
* Uncertainty of the fused estimate: Eq. 23 averages two estimates, so its variance
  is (delta_u^2 + delta_p^2) / 4 (positions) and (s_u^2 + s_p^2) / 4 (headings),
  which is the prior uncertainty of the next step.
"""

from __future__ import annotations

import numpy as np

from coordinator.localization.dead_reckoning import dead_reckon
from coordinator.localization.graph import require_observable
from coordinator.localization.movers import LOCAL_MIN, GlobalTopology, region_topology
from coordinator.localization.superimpose import fusion_weights, superimpose
from coordinator.localization.topology import Topology, estimate_topology
from runtime.models.config import ModelConfig
from runtime.models.geometry import rotate, wrap_angle
from runtime.models.state import Observations, StepCommands, SwarmEstimate


class PaperLocalizer:
    """Sequential localization of the paper: cluster the observations, then superimpose."""

    name = "paper"

    def __init__(self, cfg: ModelConfig, huber: float | None = None, local_min: int = LOCAL_MIN) -> None:
        self.cfg = cfg
        self.huber = huber  # metres; None = plain least squares of Eq. B3
        self.local_min = local_min  # robots from which a step is localized around its movers (``movers``)

    def topology(self, ids: np.ndarray, obs: Observations, initial_poses: np.ndarray | None = None) -> Topology:
        """Phase 1.2 alone: the topology in the reference robot's frame."""
        ids = np.asarray(ids, dtype=np.int64)
        i, j = self._observable(ids, obs)
        return estimate_topology(
            len(ids), i, j, obs.range_m, obs.bearing_rad, self.cfg, initial_poses=initial_poses, huber=self.huber
        )

    @staticmethod
    def _observable(ids: np.ndarray, obs: Observations) -> tuple[np.ndarray, np.ndarray]:
        """The observations' (observer, observed) indices into ``ids``; ``LocalizationError`` when not every robot can
        be localized (``graph.require_observable``)."""
        i, j = obs.indexed(ids)
        require_observable(ids, i, j)
        return i, j

    def localize(self, prior: SwarmEstimate, step: StepCommands, obs: Observations) -> SwarmEstimate:
        """Post-step estimate (Eq. 23) from the pre-step estimate, the commands and the observations; from
        ``local_min`` robots the topology of the movers' region where it is small (``movers``)."""
        dr = dead_reckon(prior, step, self.cfg)  # Phase 1.1
        delta_u = dr.delta
        topo: Topology | GlobalTopology
        held: np.ndarray | slice = slice(None)  # the robots whose dead reckoning places the topology (Eq. 21-22)
        if prior.n < self.local_min:
            topo = self.topology(prior.ids, obs, initial_poses=dr.poses)  # Phase 1.2
        else:
            i, j = self._observable(prior.ids, obs)
            local = region_topology(dr.poses, step.moving, i, j, obs.range_m, obs.bearing_rad, self.cfg, self.huber)
            if local is not None:  # in the global frame, superimposed onto the still robots (``movers``: no drift)
                topo, held = local, ~step.moving
            else:
                topo = estimate_topology(prior.n, i, j, obs.range_m, obs.bearing_rad, self.cfg, initial_poses=dr.poses,
                                         huber=self.huber)
        weights = fusion_weights(topo.delta_p, delta_u)
        theta, t = superimpose(topo.positions[held], dr.positions[held], weights[held])  # Eq. 21-22
        poses, cov = fuse(topo.positions, topo.headings, topo.delta_p, topo.heading_sigma, theta, t, dr.poses, dr.cov, delta_u)
        return SwarmEstimate(prior.ids, poses, cov)

    def localize_subset(self, prior: SwarmEstimate, step: StepCommands, obs: Observations, keep: np.ndarray) -> SwarmEstimate:
        """Post-step estimate of the whole swarm, localizing the robots where ``keep`` (n,) from the
        observations among them; the others keep their dead reckoning (``partial.localize_observable``)."""
        if keep.all():
            return self.localize(prior, step, obs)
        i, j = obs.indexed(prior.ids)
        sub = self.localize(prior.select(keep), step.select(keep), obs.select(keep[i] & keep[j]))
        return dead_reckon(prior, step, self.cfg).with_subset(keep, sub)


def fuse(
    topo_positions: np.ndarray,
    topo_headings: np.ndarray,
    delta_p: np.ndarray,
    heading_sigma: np.ndarray,
    theta: np.ndarray,
    t: np.ndarray,
    dr_poses: np.ndarray,
    dr_cov: np.ndarray,
    delta_u: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 15 and 23: the topology mapped by (theta, t) averaged with dead reckoning, and the fused covariance.

    Batched over leading axes: positions (..., n, 2), headings (..., n) (NaN = no heading), theta (...),
    t (..., 2), dr_poses (..., n, 3), dr_cov (..., n, 3, 3), delta_u (..., n). Returns poses and covariances.
    """
    theta = np.asarray(theta)
    topo_global = rotate(theta[..., None], topo_positions) + t[..., None, :]  # Eq. 15
    positions = 0.5 * (topo_global + dr_poses[..., :2])  # Eq. 23

    has_heading = np.isfinite(topo_headings)
    topo_heading = wrap_angle(np.where(has_heading, topo_headings, 0.0) + theta[..., None])
    dr_heading = dr_poses[..., 2]
    heading = np.where(has_heading, wrap_angle(dr_heading + 0.5 * wrap_angle(topo_heading - dr_heading)), dr_heading)

    var_xy = (delta_u**2 + delta_p**2) / 4.0
    var_h = np.where(has_heading, (dr_cov[..., 2, 2] + np.where(has_heading, heading_sigma, 0.0) ** 2) / 4.0, dr_cov[..., 2, 2])
    cov = np.zeros(dr_cov.shape)
    cov[..., 0, 0] = cov[..., 1, 1] = var_xy / 2.0
    cov[..., 2, 2] = var_h
    return np.concatenate([positions, heading[..., None]], axis=-1), cov
