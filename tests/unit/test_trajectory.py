"""Trajectory files, validation and the random generator of Section 7."""

from __future__ import annotations

import json

import numpy as np
import pytest

from runtime.errors import SwarmInputError
from runtime.models.trajectory import Trajectory, is_connected, min_separation, random_trajectory, validate_connected


def test_random_trajectories_change_pose_and_topology_and_stay_connected():
    traj = random_trajectory(10, 20, np.random.default_rng(1))
    assert traj.configurations.shape == (20, 10, 2)
    for config in traj.configurations:
        assert is_connected(config, 0.5)
    shape = [np.linalg.norm(c[:, None] - c[None], axis=-1) for c in traj.configurations]
    assert all(not np.allclose(a, b, atol=1e-3) for a, b in zip(shape, shape[1:], strict=False))  # topology changes
    np.testing.assert_array_equal(random_trajectory(10, 5, np.random.default_rng(3)).configurations,
                                  random_trajectory(10, 5, np.random.default_rng(3)).configurations)


@pytest.mark.parametrize("n", [2, 3, 1000])
def test_random_trajectories_of_any_size_are_connected_and_kept_apart(n):
    traj = random_trajectory(n, 3, np.random.default_rng(n), sensing_range=0.5)
    validate_connected(traj, 0.9 * 0.5)  # the generator's margin
    for config in [traj.initial_poses[:, :2], *traj.configurations]:
        assert min_separation(config) >= 0.25 * 0.2 - 1e-12
    start = traj.initial_poses[:, :2]
    assert np.all(np.abs(start) <= np.sqrt(n) * 0.2 / 2 + 1e-12)  # the start fills its square
    moved = np.linalg.norm(traj.configurations[0].mean(axis=0) - start.mean(axis=0))
    assert moved == pytest.approx(0.3, abs=0.06)  # the rigid step of 0.3 m (plus the mean of the reshaping)
    travel = np.linalg.norm(np.diff(np.concatenate([start[None], traj.configurations]), axis=0), axis=2)
    assert travel.max() < 0.3 + 0.3 + 5 * 0.06 * np.sqrt(2)  # step + rotation at the edge + reshaping: under 1 m, the agents' limit
    again = random_trajectory(n, 3, np.random.default_rng(n), sensing_range=0.5)
    np.testing.assert_array_equal(again.configurations, traj.configurations)
    np.testing.assert_array_equal(again.initial_poses, traj.initial_poses)


def test_large_swarms_still_change_topology():
    traj = random_trajectory(300, 2, np.random.default_rng(4))
    a, b = (c - c.mean(axis=0) for c in traj.configurations)
    reshaped = np.linalg.norm(b - a @ _best_rotation(a, b), axis=1)  # what is left after the rigid move
    assert np.median(reshaped) > 0.03  # most robots are displaced (N(0, 6 cm) per axis), not frozen


def _best_rotation(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    u, _, vt = np.linalg.svd(a.T @ b)
    return u @ vt


@pytest.mark.parametrize(
    "n,configs,sensing,message",
    [
        (1, 3, 0.5, "robots must be >= 2 for a random trajectory, got 1"),
        (0, 3, 0.5, "robots must be >= 2 for a random trajectory, got 0"),
        (-2, 3, 0.5, "robots must be >= 2 for a random trajectory, got -2"),
        (5, 0, 0.5, "configs must be >= 1 for a random trajectory, got 0"),
        (5, 2, 0.05, "sensing_range is too small"),
    ],
)
def test_random_trajectory_options_are_checked_up_front(n, configs, sensing, message):
    with pytest.raises(SwarmInputError) as info:
        random_trajectory(n, configs, np.random.default_rng(0), sensing_range=sensing)
    assert str(info.value).startswith(message)  # the parameter; the command line names the flag (below)


def test_round_trip(tmp_path):
    traj = random_trajectory(6, 3, np.random.default_rng(2))
    traj.save(tmp_path / "t.json")
    back = Trajectory.load(tmp_path / "t.json")
    np.testing.assert_array_equal(back.configurations, traj.configurations)
    np.testing.assert_array_equal(back.initial_poses, traj.initial_poses)


@pytest.mark.parametrize(
    "doc,message",
    [
        ({"robots": [0, 1]}, "'robots', 'initial_poses' and 'configurations'"),
        ({"robots": [0, 1], "initial_poses": [[0, 0, 0]], "configurations": [[[0, 0], [0.1, 0]]]}, "initial_poses must be 2 rows"),
        ({"robots": [0, 1], "initial_poses": [[0, 0, 0], [0.1, 0, 0]], "configurations": [[[0, 0], [None, 0]]]},
         "configuration 1 holds NaN/inf for robots [1]"),
        ({"robots": [0, 1], "initial_poses": [[0, 0, 0], [0.1, 0, 0]], "configurations": []}, "non-empty"),
        ({"robots": [0, 0], "initial_poses": [[0, 0, 0], [0.1, 0, 0]], "configurations": [[[0, 0], [0, 1]]]}, "duplicate robot ids"),
    ],
)
def test_bad_trajectories_are_named(tmp_path, doc, message):
    path = tmp_path / "t.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(SwarmInputError) as info:
        Trajectory.load(path)
    assert message in str(info.value)


def test_impossible_trajectory_names_configuration_and_robots():
    traj = Trajectory([0, 1, 2], [[0, 0, 0], [0.2, 0, 0], [0.1, 0.2, 0]], [[[0, 0], [0.2, 0], [0.1, 0.2]], [[0, 0], [0.2, 0], [5, 5]]])
    with pytest.raises(SwarmInputError, match=r"configuration 2 is not connected .* robots \[2\]"):
        validate_connected(traj, 0.5)
