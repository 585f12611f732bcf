"""The inchworm executor end to end on the in-process simulated backend."""

from __future__ import annotations

import numpy as np
import pytest

from coordinator.executor import InchwormExecutor
from coordinator.localization import make_localizer
from coordinator.selection.genetic import GeneticConfig
from coordinator.selection.selector import SelectionConfig
from coordinator.simulate import initial_estimate, simulate
from coordinator.strategies import make_strategy
from runtime.models.config import ModelConfig
from runtime.models.simulation import SimulatedSwarm
from runtime.models.state import Observations
from runtime.models.trajectory import random_trajectory

POINTS = ModelConfig(robot_radius_m=0.0)  # the paper's point robots: these tests pin its selection and execution maths (bodies: test_bodies.py)

FAST = SelectionConfig(samples=4, genetic=GeneticConfig(population=6, generations=2))


@pytest.fixture(scope="module")
def traj():
    return random_trajectory(6, 3, np.random.default_rng(7))


def test_end_to_end_is_bounded_and_bit_for_bit_reproducible(traj):
    a = simulate(traj, "inchworm", POINTS, selection=FAST, seed=3)
    b = simulate(traj, "inchworm", POINTS, selection=FAST, seed=3)
    assert len(a.configs) == 3
    # e_l (Eq. 8) and P_f (Eq. 24, 25) from the recorded truths and estimates, written out here
    truths = np.array([a.initial_truth[:, :2], *[c.truth[:, :2] for c in a.configs]])
    estimates = np.array([c.estimate.poses[:, :2] for c in a.configs])
    np.testing.assert_allclose(a.localization_errors(), np.linalg.norm(truths[1:] - estimates, axis=-1).mean(axis=1), rtol=1e-12)
    m_bar = sum(np.linalg.norm(truths[j] - truths[j - 1], axis=1).mean() for j in range(1, 4))
    final_error = np.linalg.norm(truths[-1] - traj.configurations[2], axis=1).mean()
    assert a.pf() == pytest.approx(final_error / m_bar, rel=1e-12)
    for sa, sb in zip(a.steps, b.steps, strict=True):
        np.testing.assert_array_equal(sa.estimate.poses, sb.estimate.poses)
        np.testing.assert_array_equal(sa.truth, sb.truth)
    assert a.pf() == b.pf()
    c = simulate(traj, "inchworm", POINTS, selection=FAST, seed=4)
    assert c.pf() != a.pf()


@pytest.mark.parametrize("method", ["ref57", "inchworm"])
def test_noise_free_run_reaches_every_configuration_exactly(traj, method):
    """No motion or sensing noise and an exact start: every command lands, every estimate is the truth.

    So e_l = 0 and the following error is 0 after each configuration, P_f = 0, and the
    average total motion (Eq. 25) is that of the desired configurations themselves:
    sum_j mean_i |C_j,i - C_j-1,i| with C_0 the initial positions.
    """
    exact = ModelConfig(turn_sigma_rad=0.0, drive_sigma_frac=0.0, range_sigma_m=0.0, bearing_sigma_rad=0.0)
    run = simulate(traj, method, exact, selection=FAST, seed=5, initial_delta=0.0, initial_heading_sigma=0.0)
    np.testing.assert_allclose(run.localization_errors(), 0.0, atol=1e-9)
    np.testing.assert_allclose(run.following_errors(), 0.0, atol=1e-9)
    assert run.pf() == pytest.approx(0.0, abs=1e-9)
    desired = np.array([traj.initial_poses[:, :2], *traj.configurations[:3]])
    expected = np.cumsum([np.linalg.norm(desired[j] - desired[j - 1], axis=1).mean() for j in range(1, 4)])
    np.testing.assert_allclose(run.travelled(), expected, rtol=1e-9)


@pytest.mark.parametrize(
    "method,n_a,steps",
    [("ref57", 3, 2), ("no-anchors", 0, 1), ("one-at-a-time", 5, 6), ("heuristic-fixed", 3, 2), ("inchworm-equal-speed", 3, 2)],
)
def test_baselines_have_their_speed(traj, method, n_a, steps):
    run = simulate(traj, method, POINTS, selection=FAST, seed=1)
    assert run.anchor_counts().tolist() == [n_a] * 3
    assert run.steps_per_config().tolist() == [steps] * 3
    assert len(run.steps) == 3 * steps
    before = run.initial_truth
    for rec in run.steps:
        moved = np.any(rec.truth != before, axis=1)
        assert not np.any(moved & ~rec.moving)  # anchors never move
        before = rec.truth


def test_ref57_halves_are_fixed_for_the_whole_run(traj):
    run = simulate(traj, "ref57", POINTS, seed=2)
    keys = {c.plan.key() for c in run.configs}
    assert len(keys) == 1


class BlindSwarm(SimulatedSwarm):
    """A backend whose sensors return nothing."""

    def observe(self) -> Observations:
        return Observations.empty()


def test_localization_failure_keeps_dead_reckoning_and_says_why(traj):
    cfg = POINTS
    backend = BlindSwarm(traj.ids, traj.initial_poses, cfg, seed=0)
    strategy = make_strategy("ref57", traj.n, cfg, make_localizer("paper", cfg), FAST, seed=0)
    run = InchwormExecutor(backend, make_localizer("paper", cfg), strategy, cfg).run(traj, initial_estimate(traj, 0, 0.01, 0.03))
    assert all(s.fallback == "dead reckoning kept for robots [0, 1, 2, 3, 4, 5] (unobserved)" for s in run.steps)


def test_equal_speed_keeps_its_anchor_count_when_no_plan_keeps_connectivity():
    from runtime.models.state import SwarmEstimate

    strategy = make_strategy("inchworm-equal-speed", 4, POINTS, make_localizer("paper", POINTS), FAST, seed=0)
    estimate = SwarmEstimate.isotropic([0, 1, 2, 3], np.array([[0, 0, 0], [0.45, 0, 0], [0.9, 0, 0], [1.35, 0, 0]], float), 0.01, 0.02)
    desired = np.array([[0, 0.1], [0.45, 0.1], [0.9, 0.1], [1.35, 0.1]]) + [[0, 0], [0.4, 0.0], [0.8, 0], [1.2, 0]]
    plan, selection = strategy.plan(estimate, desired)
    assert selection is None and plan.n_anchors == 2


class Recorder:
    def __init__(self) -> None:
        self.events = []

    def on_plan(self, config_index, first_step, plan, selection) -> None:
        self.events.append(("plan", config_index, first_step, plan.n_steps))

    def on_estimate(self, step, estimate) -> None:
        self.events.append(("estimate", step, estimate.poses.copy()))


def test_listener_sees_plans_and_estimates_with_global_steps_and_changes_nothing(traj):
    cfg = POINTS

    def run(listener):
        backend = SimulatedSwarm(traj.ids, traj.initial_poses, cfg, seed=5)
        strategy = make_strategy("ref57", traj.n, cfg, make_localizer("paper", cfg), FAST, seed=5)
        return InchwormExecutor(backend, make_localizer("paper", cfg), strategy, cfg, listener=listener).run(
            traj, initial_estimate(traj, 5, 0.01, 0.03))

    rec = Recorder()
    plain, heard = run(None), run(rec)
    assert [e[:4] for e in rec.events if e[0] == "plan"] == [("plan", 0, 1, 2), ("plan", 1, 3, 2), ("plan", 2, 5, 2)]
    estimates = [e for e in rec.events if e[0] == "estimate"]
    assert [e[1] for e in estimates] == list(range(7))
    np.testing.assert_array_equal(estimates[0][2], heard.initial_estimate.poses)
    for e, s, p in zip(estimates[1:], heard.steps, plain.steps, strict=True):
        np.testing.assert_array_equal(e[2], s.estimate.poses)
        np.testing.assert_array_equal(s.estimate.poses, p.estimate.poses)
    assert rec.events.index(("plan", 1, 3, 2)) == 4  # after the estimates 0, 1, 2 and before step 3's
