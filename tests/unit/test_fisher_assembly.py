"""The one assembly of the Fisher information (``crlb.fisher_informations``), which serves the single-swarm bound
(``crlb.fisher_information``) and the anchor search's prediction (``crlb_rank.crlb_blocks``), against a hand
computation: I = blockdiag(P_i^-1) + sum over observations of H^T R^-1 H, H written out row by row."""

from __future__ import annotations

import math

import numpy as np

from coordinator.localization.crlb import fisher_information, fisher_informations
from coordinator.selection.crlb_rank import crlb_blocks
from runtime.models.config import ModelConfig

CFG = ModelConfig()


def hand_information(poses: np.ndarray, cov: np.ndarray, observations: list[tuple[int, int]]) -> np.ndarray:
    """Eq. 20's range and bearing of robot j seen by robot i, differentiated by hand, one observation at a time."""
    n = len(poses)
    s_r, s_b = CFG.range_sigma_m, CFG.bearing_sigma_rad
    info = np.zeros((3 * n, 3 * n))
    for i in range(n):
        info[3 * i : 3 * i + 3, 3 * i : 3 * i + 3] += np.linalg.inv(cov[i])
    for i, j in observations:
        dx, dy = poses[j, 0] - poses[i, 0], poses[j, 1] - poses[i, 1]
        rho = math.hypot(dx, dy)
        sigma_b = s_b * math.sqrt(1.0 + (3.0 * s_r / rho) ** 4)  # the bearing sigma gated by the range (range_bearing)
        h = np.zeros((2, 3 * n))  # rows: range, bearing
        h[0, 3 * j : 3 * j + 2] = [dx / rho, dy / rho]
        h[0, 3 * i : 3 * i + 2] = [-dx / rho, -dy / rho]
        h[1, 3 * j : 3 * j + 2] = [-dy / rho**2, dx / rho**2]
        h[1, 3 * i : 3 * i + 2] = [dy / rho**2, -dx / rho**2]
        h[1, 3 * i + 2] = -1.0  # the bearing is measured in the observer's frame
        info += h.T @ np.diag([1.0 / s_r**2, 1.0 / sigma_b**2]) @ h
    return info


def rough_case() -> tuple[np.ndarray, np.ndarray]:
    """Two swarms of five robots: correlated covariances, robots seen at bearings
    of +-pi (straight behind the observer, 1e-9 m to either side), a near pair and one at 0.49 m."""
    rng = np.random.default_rng(11)
    poses = np.zeros((2, 5, 3))
    poses[0] = [[0.0, 0.0, 0.0], [-0.3, 1e-9, np.pi - 1e-9], [-0.3, -1e-9, -np.pi], [0.05, 0.02, 2.0], [0.2, 0.45, -1.5]]
    poses[1] = [[0.1, 0.1, np.pi], [0.4, 0.1 + 1e-9, 0.3], [0.1, 0.59, -3.0], [0.12, 0.08, 1.0], [-0.2, 0.3, -np.pi + 1e-9]]
    mix = rng.normal(size=(2, 5, 3, 3)) * np.array([0.01, 0.02, 0.05])[:, None]
    cov = mix @ np.swapaxes(mix, -1, -2) + np.diag([1e-6, 1e-6, 1e-5])  # full 3x3 correlations
    return poses, cov


def test_the_assembly_is_the_hand_computation_for_one_swarm_and_for_a_batch():
    poses, cov = rough_case()
    observations = [
        [(0, 1), (0, 2), (1, 0), (2, 0), (0, 3), (3, 0), (3, 4), (4, 3), (1, 2), (0, 1)],  # (0, 1) twice: counted twice
        [(0, 1), (1, 0), (0, 2), (3, 0), (0, 3), (4, 0), (0, 4), (3, 4), (2, 4)],
    ]
    hand = [hand_information(poses[k], cov[k], observations[k]) for k in range(2)]
    swarm = np.concatenate([np.full(len(obs), k) for k, obs in enumerate(observations)])
    pairs = np.array([p for obs in observations for p in obs])
    batch = fisher_informations(poses, cov, swarm, pairs[:, 0], pairs[:, 1], CFG)
    for k in range(2):
        alone = fisher_information(poses[k], cov[k], *np.array(observations[k]).T, CFG)
        scale = np.abs(hand[k]).max()
        np.testing.assert_allclose(alone, hand[k], rtol=1e-9, atol=1e-12 * scale)
        np.testing.assert_array_equal(batch[k], alone)  # one swarm or many: the same entries, summed in the same order
        np.testing.assert_array_equal(alone, alone.T)  # each entry and its mirror summed alike


def test_the_search_bound_is_the_inverse_of_the_hand_information_within_sensing_range():
    poses, cov = rough_case()
    blocks = crlb_blocks(poses, cov, CFG)
    for k in range(2):
        gap = np.linalg.norm(poses[k, :, None, :2] - poses[k, None, :, :2], axis=-1)
        within = [(i, j) for i in range(5) for j in range(5) if i != j and gap[i, j] <= CFG.sensing_range_m]
        assert len(within) < 20  # some pairs out of range
        inverse = np.linalg.inv(hand_information(poses[k], cov[k], within))
        for r in range(5):
            np.testing.assert_allclose(blocks[k, r], inverse[3 * r : 3 * r + 3, 3 * r : 3 * r + 3], rtol=1e-8, atol=1e-15)
