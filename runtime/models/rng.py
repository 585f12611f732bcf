"""Seeded random streams, one per robot and purpose, so that a run is reproducible
whether robots are simulated in one process or as separate agent processes.

No global RNG is used anywhere: every random draw takes an explicit ``numpy.random.Generator``.
"""

from __future__ import annotations

from enum import IntEnum

import numpy as np


class Stream(IntEnum):
    """Purpose of a per-robot random stream."""

    MOTION = 0
    SENSING = 1


def robot_rng(seed: int, robot_id: int, stream: Stream) -> np.random.Generator:
    """The generator robot ``robot_id`` uses for ``stream`` in a run seeded with ``seed``."""
    return np.random.Generator(np.random.PCG64(np.random.SeedSequence(seed, spawn_key=(int(robot_id), int(stream)))))


def robot_rngs(seed: int, robot_ids: np.ndarray | list[int], stream: Stream) -> list[np.random.Generator]:
    """One generator per robot, in the order of ``robot_ids``."""
    return [robot_rng(seed, int(r), stream) for r in robot_ids]
