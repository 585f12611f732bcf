"""Checkpoints: the executor's state round-trips exactly, and a run resumed from any checkpoint by a new executor
(another coordinator) on the same robots ends exactly as the uninterrupted run (in-process simulated swarm), with
the same steps split for bodies (every method here splits some) and the same contacts."""

from __future__ import annotations

import numpy as np
import pytest

from coordinator.checkpoint import RunState
from coordinator.executor import InchwormExecutor
from coordinator.localization import make_localizer
from coordinator.selection.genetic import GeneticConfig
from coordinator.selection.selector import SelectionConfig
from coordinator.simulate import initial_estimate
from coordinator.strategies import make_strategy
from runtime.errors import SwarmInputError
from runtime.models.config import ModelConfig
from runtime.models.simulation import SimulatedSwarm
from runtime.models.trajectory import random_trajectory

FAST = SelectionConfig(samples=4, genetic=GeneticConfig(population=6, generations=2))
CFG = ModelConfig()


class Died(Exception):
    """The coordinator died right after publishing a checkpoint."""


def _executor(backend, traj, method: str, seed: int, on_checkpoint) -> InchwormExecutor:
    localizer = make_localizer("paper", CFG)
    strategy = make_strategy(method, traj.n, CFG, localizer, FAST, seed)
    return InchwormExecutor(backend, localizer, strategy, CFG, on_checkpoint=on_checkpoint)


def _split(record) -> tuple | None:
    """How the body constraint split a configuration's plan: the strategy's plan, robots left unclear, margin."""
    r = record.regrouped
    return None if r is None else (r.planned.order.tolist(), r.planned.sizes, r.unclear, r.sigmas)


@pytest.fixture(scope="module")
def traj():
    return random_trajectory(10, 3, np.random.default_rng(11))


@pytest.mark.parametrize("method", ["inchworm", "inchworm-equal-speed", "ref57"])
def test_a_run_resumed_from_every_checkpoint_ends_bit_for_bit_as_the_uninterrupted_one(traj, method):
    seed = 5
    start = initial_estimate(traj, seed, 0.01, np.radians(2.0))
    states: list[RunState] = []
    clean = _executor(SimulatedSwarm(traj.ids, traj.initial_poses, CFG, seed), traj, method, seed, states.append).run(traj, start)
    assert states[-1].finished and not any(s.finished for s in states[:-1])
    for k, state in enumerate(states[:-1]):
        assert RunState.from_json(state.to_json(), traj, start).to_json() == state.to_json()
        backend = SimulatedSwarm(traj.ids, traj.initial_poses, CFG, seed)  # the robots: they outlive the coordinator
        seen: list[RunState] = []

        def die_at_k(s: RunState, seen: list[RunState] = seen, k: int = k) -> None:
            seen.append(s)
            if len(seen) == k + 1:
                raise Died

        with pytest.raises(Died):
            _executor(backend, traj, method, seed, die_at_k).run(traj, start)
        taken = RunState.from_json(seen[-1].to_json(), traj, start)
        resumed = _executor(backend, traj, method, seed, None).run(traj, start, resume=taken)
        assert resumed.pf() == clean.pf()
        for a, b in zip(resumed.steps, clean.steps, strict=True):
            np.testing.assert_array_equal(a.estimate.poses, b.estimate.poses)
            np.testing.assert_array_equal(a.estimate.cov, b.estimate.cov)
            np.testing.assert_array_equal(a.truth, b.truth)
        assert [c.plan.sizes for c in resumed.configs] == [c.plan.sizes for c in clean.configs]
        assert [_split(c) for c in resumed.configs] == [_split(c) for c in clean.configs]
        assert resumed.steps_added() == clean.steps_added()
        assert clean.steps_added() > 0 or method == "inchworm"  # its selection repairs crowded plans: no split needed here
        assert resumed.contacts(CFG.robot_radius_m) == clean.contacts(CFG.robot_radius_m)
        np.testing.assert_array_equal(resumed.anchor_counts(), clean.anchor_counts())


def test_an_unreadable_state_is_a_clear_error(traj):
    start = initial_estimate(traj, 0, 0.01, 0.03)
    for text in ("{}", "[1]", '{"step": 1}', "not json"):
        with pytest.raises(SwarmInputError, match="checkpoint state is not readable"):
            RunState.from_json(text, traj, start)
