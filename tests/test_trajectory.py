"""Trajectory files, validation and the random generator of Section 7."""

from __future__ import annotations

import json

import numpy as np
import pytest

from runtime.errors import SwarmInputError
from runtime.trajectory import Trajectory, is_connected, random_trajectory, validate_connected


def test_random_trajectories_change_pose_and_topology_and_stay_connected():
    traj = random_trajectory(10, 20, np.random.default_rng(1))
    assert traj.configurations.shape == (20, 10, 2)
    for config in traj.configurations:
        assert is_connected(config, 0.5)
    shape = [np.linalg.norm(c[:, None] - c[None], axis=-1) for c in traj.configurations]
    assert all(not np.allclose(a, b, atol=1e-3) for a, b in zip(shape, shape[1:]))  # topology changes
    np.testing.assert_array_equal(random_trajectory(10, 5, np.random.default_rng(3)).configurations,
                                  random_trajectory(10, 5, np.random.default_rng(3)).configurations)


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
        ({"robots": [0, 1], "initial_poses": [[0, 0, 0], [0.1, 0, 0]], "configurations": [[[0, 0], [None, 0]]]}, "configuration 1 holds NaN/inf for robots [1]"),
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
