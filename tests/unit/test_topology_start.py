"""A large swarm's topology solve starts turned to its observations' headings (``topology.aligned_start``): the same
solution as from the plain start, in fewer iterations."""

from typing import Any

import numpy as np
import pytest

import coordinator.localization.sparse_lm as sparse_lm
import coordinator.localization.topology as topology
from runtime.models.config import ModelConfig
from runtime.models.rng import Stream, robot_rngs
from runtime.models.sensing import sense_swarm
from runtime.models.trajectory import body_spacing, random_trajectory

CFG = ModelConfig()


def solve(monkeypatch: pytest.MonkeyPatch, align_min: int, truth: np.ndarray, start: np.ndarray,
          seed: int) -> tuple[topology.Topology, int]:
    """(topology, iterations) of the observations of ``truth`` from ``start`` with ``ALIGN_MIN`` = ``align_min``."""
    monkeypatch.setattr(topology, "ALIGN_MIN", align_min)
    ids = np.arange(len(truth))
    obs = sense_swarm(truth, ids, CFG, robot_rngs(seed, ids, Stream.SENSING))
    i, j = obs.indexed(ids)
    runs = []
    lm = sparse_lm.levenberg_marquardt

    def counted(*args: Any, **kwargs: Any) -> sparse_lm.LsqResult:
        runs.append(lm(*args, **kwargs))
        return runs[-1]

    monkeypatch.setattr(topology, "levenberg_marquardt", counted)
    topo = topology.estimate_topology(len(ids), i, j, obs.range_m, obs.bearing_rad, CFG, initial_poses=start)
    return topo, runs[0].iterations


@pytest.mark.parametrize("seed", [1])
def test_aligned_start_finds_the_same_topology(monkeypatch: pytest.MonkeyPatch, seed: int) -> None:
    rng = np.random.default_rng(seed)
    traj = random_trajectory(300, 1, rng, sensing_range=CFG.sensing_range_m, **body_spacing(CFG))
    truth = traj.initial_poses.copy()
    truth[:, 2] = rng.choice([-np.pi, np.pi - 1e-9, 0.5], len(truth)) + rng.normal(0.0, 0.01, len(truth))  # near +-pi
    start = truth + np.column_stack([rng.normal(0.0, 0.01, (len(truth), 2)), rng.normal(0.0, 0.05, len(truth))])
    start[0, 2] += 0.05  # the reference robot's heading 3 degrees off: the whole swarm turned about it
    plain, plain_iterations = solve(monkeypatch, 10**9, truth, start, seed)
    aligned, aligned_iterations = solve(monkeypatch, 0, truth, start, seed)
    assert aligned_iterations < plain_iterations
    assert np.max(np.abs(aligned.solved_positions - plain.solved_positions)) < 1e-6  # the same minimum (m)
    assert np.max(np.abs(aligned.positions - plain.positions)) < 1e-6
    assert aligned.reference == plain.reference


def test_aligned_start_keeps_the_reference_and_robots_that_observe_nobody() -> None:
    start = np.array([[0.0, 0.0, 0.0], [0.3, 0.0, 3.1], [0.0, 0.3, -3.1], [0.2, 0.2, 1.0]])
    observer, observed = np.array([0, 0, 1]), np.array([1, 2, 0])
    bearing = np.array([-0.1, np.pi / 2 - 0.1, np.pi - 3.1 + 0.2])  # the reference's heading off by 0.1 rad
    out = topology.aligned_start(start, observer, observed, bearing, 0)
    assert out[0].tolist() == [0.0, 0.0, 0.0]  # the gauge stays
    np.testing.assert_allclose(out[1, :2], [0.3 * np.cos(-0.1), 0.3 * np.sin(-0.1)])  # turned about the reference
    np.testing.assert_allclose(out[1, 2], 3.1 - 0.2 - 0.1)  # its own misfit, less the reference's
    np.testing.assert_allclose(out[3, 2], 1.0 - 0.1)  # observes nobody: turned with the swarm only
