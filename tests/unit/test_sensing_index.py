"""Sensing of large swarms: ``sense_swarm`` finds every robot's neighbours at once (a k-d tree from ``INDEX_MIN``
robots) and draws the same numbers as ``sense_robot`` robot by robot (docs/benchmarks.md, "Bodies at scale")."""

import numpy as np
import pytest

import runtime.models.sensing as sensing
from runtime.models.config import ModelConfig
from runtime.models.rng import Stream, robot_rngs
from runtime.models.sensing import neighbour_pairs, sense_robot, sense_swarm


def robot_by_robot(poses: np.ndarray, ids: np.ndarray, cfg: ModelConfig, seed: int) -> tuple[np.ndarray, ...]:
    """The observations of ``sense_robot`` called for each robot in turn (what ``sense_swarm`` must equal)."""
    out = [sense_robot(poses, i, cfg, rng) for i, rng in enumerate(robot_rngs(seed, ids, Stream.SENSING))]
    empty = [np.zeros(0, np.int64)]
    observer = np.concatenate([np.full(len(nb), ids[i]) for i, (nb, _, _) in enumerate(out)] + empty)
    observed = np.concatenate([ids[nb] for nb, _, _ in out] + empty)
    return observer, observed, np.concatenate([o[1] for o in out] + [np.zeros(0)]), np.concatenate([o[2] for o in out] + [np.zeros(0)])


def rough_swarm(n: int, seed: int, cfg: ModelConfig) -> np.ndarray:
    """``n`` poses: a random spread, pairs exactly at the sensing range (along an axis and a diagonal), a crowd of
    robots on one spot (all within range of each other, zero distances), headings near +-pi."""
    rng = np.random.default_rng(seed)
    poses = np.column_stack([rng.uniform(0.0, 0.3 * np.sqrt(n), (n, 2)), rng.choice([-np.pi, np.pi - 1e-12, 0.3], n)])
    r = cfg.sensing_range_m
    if n >= 4:  # exactly r apart (sums exact in binary), and r apart up to rounding
        poses[0, :2], poses[1, :2] = [1.0, 1.0], [1.0 + r, 1.0]
        poses[3, :2] = poses[2, :2] + r * np.array([np.cos(0.7), np.sin(0.7)])
    if n >= 20:
        poses[10:20, :2] = poses[9, :2]  # ten robots in one grid cell, at one point
    return poses


@pytest.mark.parametrize("n", [0, 1, 2, 5, 127, 128, 300])
@pytest.mark.parametrize("dropout", [0.0, 0.4])
def test_sense_swarm_is_sense_robot_for_each_robot(n: int, dropout: float) -> None:
    cfg = ModelConfig(dropout_prob=dropout)
    poses, ids = rough_swarm(n, n, cfg), np.arange(n, dtype=np.int64) * 3 + 7
    obs = sense_swarm(poses, ids, cfg, robot_rngs(5, ids, Stream.SENSING))
    expected = robot_by_robot(poses, ids, cfg, 5)
    got = (obs.observer, obs.observed, obs.range_m, obs.bearing_rad)
    for a, b in zip(got, expected, strict=True):
        assert np.array_equal(a, b)  # bit for bit
    assert n < 20 or dropout > 0 or np.isin(ids[10:20], obs.observed[obs.observer == ids[9]]).all()  # the crowd sees itself


@pytest.mark.parametrize("index_min", [0, 10**9])
def test_neighbour_pairs_at_exactly_the_range(monkeypatch: pytest.MonkeyPatch, index_min: int) -> None:
    monkeypatch.setattr(sensing, "INDEX_MIN", index_min)  # the k-d tree's candidates, then every pair
    cfg = ModelConfig()
    poses = rough_swarm(200, 3, cfg)
    i, j, dist = neighbour_pairs(poses[:, :2], cfg.sensing_range_m)
    d = np.hypot(*(poses[None, :, :2] - poses[:, None, :2]).T).T
    want = np.argwhere((d <= cfg.sensing_range_m) & ~np.eye(200, dtype=bool))
    assert np.array_equal(np.column_stack([i, j]), want)  # (i, j) order, the boundary pairs in
    assert {(0, 1), (1, 0)} <= set(zip(i.tolist(), j.tolist(), strict=True))
    assert np.array_equal(dist, d[i, j])
    none = neighbour_pairs(np.zeros((0, 2)), cfg.sensing_range_m)
    assert all(len(a) == 0 for a in none)
