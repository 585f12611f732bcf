"""The seeding convention shared by every comparison and study (paired runs).

Trajectory ``t`` of a study with seed ``seed`` is drawn from the generator seeded with
``[seed, t]``; every method then runs it with the run seed ``seed + t`` (initial-estimate
error, motion and sensing noise, search), so all methods of one trajectory share their
noise streams and their P_f values are paired. Seeds belong to tasks, never to workers:
a result does not depend on how many processes ran it.
"""

from __future__ import annotations

import numpy as np

from runtime.models.trajectory import Trajectory, random_trajectory


def trajectory_rng(seed: int, t: int) -> np.random.Generator:
    """The generator of trajectory ``t`` of a study seeded with ``seed``."""
    return np.random.default_rng([seed, t])


def run_seed(seed: int, t: int) -> int:
    """The seed every method's run of trajectory ``t`` uses (noise streams shared across methods)."""
    return seed + t


def paired_trajectory(robots: int, configs: int, seed: int, t: int, sensing_range_m: float, robot_radius: float = 0.0,
                      motion_sigma: float = 0.0) -> Trajectory:
    """Trajectory ``t`` of the study: ``robots`` robots, ``configs`` random configurations (connected at ``sensing_range_m``;
    bodies kept apart as ``random_trajectory`` does, ``runtime.models.trajectory.body_spacing``)."""
    return random_trajectory(robots, configs, trajectory_rng(seed, t), sensing_range=sensing_range_m, robot_radius=robot_radius,
                             motion_sigma=motion_sigma)
