"""Checkpoints: the executor's state round-trips exactly, and a run resumed from any checkpoint by a new executor
(another coordinator) on the same robots ends exactly as the uninterrupted run (in-process simulated swarm), with
the same steps split for bodies (every method here splits some) and the same contacts; with the joint localizer
too, whose estimate carries its joint covariance from step to step."""

from __future__ import annotations

import json

import numpy as np
import pytest

from coordinator.checkpoint import RunState
from coordinator.executor import InchwormExecutor
from coordinator.localization import make_localizer
from coordinator.run_result import RunResult
from coordinator.selection.genetic import GeneticConfig
from coordinator.selection.selector import SelectionConfig
from coordinator.simulate import initial_estimate
from coordinator.strategies import make_strategy
from runtime.errors import SwarmInputError
from runtime.models.config import ModelConfig
from runtime.models.simulation import SimulatedSwarm
from runtime.models.state import SwarmEstimate
from runtime.models.trajectory import random_trajectory

FAST = SelectionConfig(samples=4, genetic=GeneticConfig(population=6, generations=2))
CFG = ModelConfig()


class Died(Exception):
    """The coordinator died right after publishing a checkpoint."""


def _executor(backend, traj, method: str, seed: int, on_checkpoint, localizer_name: str = "paper") -> InchwormExecutor:
    localizer = make_localizer(localizer_name, CFG)
    strategy = make_strategy(method, traj.n, CFG, localizer, FAST, seed)
    return InchwormExecutor(backend, localizer, strategy, CFG, on_checkpoint=on_checkpoint)


def _split(record) -> tuple | None:
    """How the body constraint split a configuration's plan: the strategy's plan, robots left unclear, margin."""
    r = record.regrouped
    return None if r is None else (r.planned.order.tolist(), r.planned.sizes, r.unclear, r.bound)


def _spread(n: int, most: int = 8) -> list[int]:
    """Every one of ``n`` checkpoints, or ``most`` of them spread from the first to the last (approach legs double a
    run's checkpoints; every one inside a leg is resumed from in tests/unit/test_legs.py)."""
    return list(range(n)) if n <= most else sorted({round(i * (n - 1) / (most - 1)) for i in range(most)})


@pytest.fixture(scope="module")
def traj():
    return random_trajectory(10, 3, np.random.default_rng(11))


@pytest.mark.parametrize(("method", "localizer"), [("inchworm", "paper"), ("inchworm-equal-speed", "paper"), ("ref57", "paper"),
                                                   ("ref57", "joint")])
def test_a_run_resumed_from_checkpoints_across_the_run_ends_bit_for_bit_as_the_uninterrupted_one(traj, method, localizer):
    seed = 5
    start = initial_estimate(traj, seed, 0.01, np.radians(2.0))
    states: list[RunState] = []
    clean = _executor(SimulatedSwarm(traj.ids, traj.initial_poses, CFG, seed), traj, method, seed, states.append, localizer).run(traj, start)
    assert (clean.steps[-1].estimate.joint is not None) == (localizer == "joint")  # what the estimate carries
    assert states[-1].finished and not any(s.finished for s in states[:-1])
    for state in states:
        assert RunState.from_json(state.to_json(), traj, start).to_json() == state.to_json()
    for k in _spread(len(states) - 1):
        backend = SimulatedSwarm(traj.ids, traj.initial_poses, CFG, seed)  # the robots: they outlive the coordinator
        seen: list[RunState] = []

        def die_at_k(s: RunState, seen: list[RunState] = seen, k: int = k) -> None:
            seen.append(s)
            if len(seen) == k + 1:
                raise Died

        with pytest.raises(Died):
            _executor(backend, traj, method, seed, die_at_k, localizer).run(traj, start)
        taken = RunState.from_json(seen[-1].to_json(), traj, start)
        resumed = _executor(backend, traj, method, seed, None, localizer).run(traj, start, resume=taken)
        assert resumed.pf() == clean.pf()
        for number, (a, b) in enumerate(zip(resumed.steps, clean.steps, strict=True), start=1):
            np.testing.assert_array_equal(a.estimate.poses, b.estimate.poses)
            np.testing.assert_array_equal(a.estimate.cov, b.estimate.cov)
            if number > taken.step:  # made after the takeover (the records of the steps before keep 3x3 blocks only)
                np.testing.assert_array_equal(a.estimate.joint, b.estimate.joint)
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


def test_the_joint_covariance_travels_as_its_upper_triangle_and_is_left_out_only_when_it_does_not_fit(traj):
    rng = np.random.default_rng(3)
    a = rng.normal(size=(3 * traj.n, 3 * traj.n))
    joint = a @ a.T + 3 * traj.n * np.eye(3 * traj.n)  # correlated
    start = initial_estimate(traj, 0, 0.01, 0.03)
    estimate = SwarmEstimate.from_joint(traj.ids, start.poses, joint)
    state = RunState(0, 0, 0, estimate, None, None, 0, RunResult("ref57", traj, start, None))
    text = state.to_json()
    assert '"triangle":"upper"' in text
    back = RunState.from_json(text, traj, start)
    np.testing.assert_array_equal(back.estimate.joint, joint)
    assert back.dropped == () and back.to_json() == text
    fits, dropped = state.bounded_json(len(text))
    assert (fits, dropped) == (text, [])
    small, dropped = state.bounded_json(len(text) - 1)
    assert dropped == ["joint"] and len(small) < len(text) // 2
    short = RunState.from_json(small, traj, start)
    assert short.estimate.joint is None and short.dropped == ("joint",)
    np.testing.assert_array_equal(short.estimate.cov, estimate.cov)
    old = json.loads(state.bounded_json(0)[0])  # as written before checkpoints carried anything: no "dropped", no joint
    del old["dropped"]
    legacy = RunState.from_json(json.dumps(old), traj, start)
    assert legacy.estimate.joint is None and legacy.dropped == ()
    np.testing.assert_array_equal(legacy.estimate.cov, estimate.cov)
    skew = joint.copy()
    skew[0, 1] = np.nextafter(skew[0, 1], np.inf)  # not symmetric bit for bit: every entry travels
    skewed = RunState(0, 0, 0, SwarmEstimate.from_joint(traj.ids, start.poses, skew), None, None, 0, RunResult("ref57", traj, start, None))
    np.testing.assert_array_equal(RunState.from_json(skewed.to_json(), traj, start).estimate.joint, skew)
