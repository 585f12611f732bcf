"""The executor without a lost robot: in-process, deterministic (the distributed path: tests/system/test_distributed.py).

``LossySwarm`` is the in-process simulated swarm that loses chosen robots after chosen
motion steps (or during planning), as the Zenoh backend reports lost agents: through
``take_lost``, after which the robot is out of ``ids`` and never commanded again.
"""

from __future__ import annotations

import numpy as np
import pytest

from coordinator.executor import (
    REJOIN_DRIVE_M,
    InchwormExecutor,
    RunAborted,
    last_estimate,
    localize_rejoined,
)
from coordinator.localization import make_localizer
from coordinator.run_result import RejoinedRobot, RunResult
from coordinator.selection.genetic import GeneticConfig
from coordinator.selection.selector import SelectionConfig
from coordinator.simulate import initial_estimate
from coordinator.strategies import METHODS, anchors_for_half, make_strategy
from runtime.models.config import ModelConfig
from runtime.models.metrics import trajectory_following_performance
from runtime.models.simulation import SimulatedSwarm
from runtime.models.state import Observations, StepCommands, SwarmEstimate
from runtime.models.trajectory import random_trajectory

FAST = SelectionConfig(samples=4, genetic=GeneticConfig(population=6, generations=2))
CFG = ModelConfig()


class LossySwarm(SimulatedSwarm):
    """Loses robot r in motion step ``lose[r]`` (0: while the first plan is made); like the Zenoh backend, it
    neither commands nor observes a robot once it is lost, and reports it at the next ``take_lost``."""

    def __init__(self, traj, seed: int, lose: dict[int, int]) -> None:
        super().__init__(traj.ids, traj.initial_poses, CFG, seed)
        self.lose, self.steps, self.calls = dict(lose), 0, 0
        self.untaken: dict[int, str] = {}
        self.commanded: list[tuple[int, list[int]]] = []  # (step, robots moved)

    def _lose(self, due: dict[int, str]) -> None:
        for r in due:
            del self.lose[r]
        self.untaken.update(due)
        keep = ~np.isin(self.ids, list(due))
        self.ids, self._poses = self.ids[keep], self._poses[keep]
        self._motion = [g for g, k in zip(self._motion, keep, strict=True) if k]
        self._sensing = [g for g, k in zip(self._sensing, keep, strict=True) if k]

    def execute(self, step: StepCommands) -> None:
        super().execute(step)
        self.steps += 1
        self.commanded.append((self.steps, step.ids[step.moving].tolist()))
        self._lose({r: f"lost after step {at}" for r, at in self.lose.items() if 0 < at <= self.steps})

    def take_lost(self) -> dict[int, str]:
        self.calls += 1
        if self.calls == 2:  # after the first plan was made
            self._lose({r: "lost after step 0" for r, at in self.lose.items() if at == 0})
        taken, self.untaken = self.untaken, {}
        return taken


def run(traj, method: str, lose: dict[int, int], seed: int = 3, **kw):
    backend = LossySwarm(traj, seed, lose)
    strategy = make_strategy(method, traj.n, CFG, make_localizer("paper", CFG), FAST, seed)
    executor = InchwormExecutor(backend, make_localizer("paper", CFG), strategy, CFG, **kw)
    return executor.run(traj, initial_estimate(traj, seed, 0.01, 0.03)), backend


class StillSeenSwarm:
    """Declares robot ``victim`` lost after motion step ``at`` (its agent stopped answering) while the robot
    stays where it is: the others still observe it and report it; its own observations no longer arrive."""

    def __init__(self, traj, seed: int, victim: int, at: int) -> None:
        self.world = SimulatedSwarm(traj.ids, traj.initial_poses, CFG, seed)
        self.ids, self.victim, self.at, self.steps = self.world.ids.copy(), victim, at, 0
        self.untaken: dict[int, str] = {}
        self.reported_victim = 0  # observations naming the lost robot handed to the executor

    def execute(self, step: StepCommands) -> None:
        full = np.isin(self.world.ids, step.ids)
        commands = np.zeros((len(full), 2))
        moving = np.zeros(len(full), bool)
        commands[full], moving[full] = step.commands, step.moving
        self.world.execute(StepCommands(self.world.ids, commands, moving))
        self.steps += 1
        if self.steps == self.at:
            self.ids = self.ids[self.ids != self.victim]
            self.untaken[self.victim] = f"no answer after step {self.at}"

    def observe(self) -> Observations:
        obs = self.world.observe()
        if self.victim in self.ids:
            return obs
        obs = obs.select(obs.observer != self.victim)  # its agent is gone; the others still see the robot
        self.reported_victim += int((obs.observed == self.victim).sum())
        return obs

    def true_poses(self) -> np.ndarray:
        return self.world.true_poses()[np.isin(self.world.ids, self.ids)]

    def take_lost(self) -> dict[int, str]:
        taken, self.untaken = self.untaken, {}
        return taken


class Recording:
    """A localizer that records, per call, the motion steps executed so far and the robots of its observations."""

    def __init__(self, inner, backend: StillSeenSwarm) -> None:
        self.inner, self.name, self.backend, self.calls = inner, inner.name, backend, []

    def localize_subset(self, prior, step, obs, keep):
        self.calls.append((self.backend.steps, set(obs.observer.tolist()) | set(obs.observed.tolist())))
        return self.inner.localize_subset(prior, step, obs, keep)


@pytest.mark.parametrize("localizer", ["paper", "joint"])
def test_a_robot_lost_while_others_still_observe_it_leaves_the_estimate(traj, localizer):
    """Robot 4 is declared lost after step 2 but stays in the field, seen by the others: their observations
    of it are reported, yet none reaches the localizer after it was lost, and it is in no later estimate."""
    backend = StillSeenSwarm(traj, 3, victim=4, at=2)
    loc = Recording(make_localizer(localizer, CFG), backend)
    strategy = make_strategy("no-anchors", traj.n, CFG, make_localizer(localizer, CFG), FAST, 3)
    result = InchwormExecutor(backend, loc, strategy, CFG).run(traj, initial_estimate(traj, 3, 0.01, 0.03))
    assert [(r.robot, r.step) for r in result.lost] == [(4, 2)] and len(result.configs) == 3
    assert backend.reported_victim > 0  # the others did see it
    assert loc.calls[0][0] == 1 and all(4 in robots for steps, robots in loc.calls if steps < 2)
    assert all(4 not in robots for steps, robots in loc.calls if steps >= 2) and loc.calls[-1][0] > 2
    assert [4 in rec.estimate.ids for rec in result.steps] == [True] + [False] * (len(result.steps) - 1)
    assert result.finished_ids.tolist() == [0, 1, 2, 3, 5]


@pytest.fixture(scope="module")
def traj():
    return random_trajectory(6, 3, np.random.default_rng(7))


@pytest.mark.parametrize("method", METHODS)
def test_every_method_finishes_without_a_robot_lost_mid_run(traj, method):
    result, backend = run(traj, method, {4: 1})
    assert len(result.configs) == 3
    assert [(r.robot, r.step) for r in result.lost] == [(4, 1)]
    assert result.finished_ids.tolist() == [0, 1, 2, 3, 5]
    assert all(4 not in moved for step, moved in backend.commanded if step > 1)
    for rec in result.steps:
        if rec.step > 0 or rec.config > 0:
            assert 4 not in rec.estimate.ids
    # P_f (Eq. 24) over the five robots that finished, from the raw records
    rows = [0, 1, 2, 3, 5]
    truths = np.stack([traj.initial_poses[rows, :2], *[c.truth[:, :2] for c in result.configs]])
    expected = trajectory_following_performance(truths[-1], traj.configurations[-1][rows], truths)
    assert result.pf() == pytest.approx(float(expected), rel=1e-12)


def test_a_robot_lost_while_planning_is_planned_without(traj):
    result, _ = run(traj, "ref57", {2: 0})
    assert result.lost[0].step == 0 and result.lost[0].robot == 2
    assert all(c.plan.n_robots == 5 for c in result.configs)
    assert result.configs[0].plan.sizes in ((3, 2), (2, 3))  # ref57's halves without robot 2


def test_remaining_groups_of_the_plan_keep_their_other_robots(traj):
    """ref57 at n = 6: groups of 3 at steps 1, 2 of each configuration; losing a robot of the second
    group after step 1 leaves that group with its two other robots, and the anchors never move."""
    result, backend = run(traj, "ref57", {})
    second = set(backend.commanded[1][1])
    victim = min(second)
    result, backend = run(traj, "ref57", {victim: 1})
    assert set(backend.commanded[1][1]) == second - {victim}
    before = None
    for rec in result.steps:
        if before is not None and np.array_equal(before[0], rec.estimate.ids):
            moved = np.any(rec.truth != before[1], axis=1)
            assert not np.any(moved & ~rec.moving)
        before = (rec.estimate.ids, rec.truth)


def test_abort_policy_and_minimum_robots(traj):
    with pytest.raises(RunAborted, match=r"lost robot 4 \(lost after step 1\); the policy for a lost robot is abort: the run ends"):
        run(traj, "no-anchors", {4: 1}, on_lost="abort")
    with pytest.raises(RunAborted, match="4 robots left, fewer than the minimum 5"):
        run(traj, "no-anchors", {4: 1, 5: 1}, min_robots=5)
    result, _ = run(traj, "no-anchors", {4: 1, 5: 2}, min_robots=4)
    assert result.finished_ids.tolist() == [0, 1, 2, 3]


def test_half_anchored_methods_keep_at_least_half_anchored():
    """n_a for n robots: n / 2 when even; else the smallest feasible count (Eq. 7) above n / 2."""
    assert [anchors_for_half(n) for n in (2, 3, 5, 6, 7, 9, 10)] == [1, 2, 4, 3, 6, 6, 5]


def test_losing_robots_until_the_trajectory_is_infeasible_ends_the_run_naming_them_with_what_was_completed():
    """Seed 2, six robots: after robots 0, 1 and 2 are lost in step 1, no anchor plan keeps the three left
    connected; the run ends as aborted by lost robots (not as bad input), with the configurations completed."""
    traj = random_trajectory(6, 3, np.random.default_rng(2))
    with pytest.raises(RunAborted, match=r"after losing robots 0, 1, 2, the robots left cannot go on after configuration 1 of 3: "
                                         r"no anchor plan keeps every robot within sensing range") as info:
        run(traj, "inchworm", {0: 1, 1: 1, 2: 1})
    assert info.value.robots == [0, 1, 2]
    result = info.value.result
    assert len(result.configs) == 1 and [r.robot for r in result.lost] == [0, 1, 2]
    assert result.finished_ids.tolist() == [3, 4, 5]


def test_a_robot_rejoining_out_of_range_comes_back_at_its_last_estimate_and_drives_back_in_steps_an_agent_accepts():
    """A rejoining robot that sees nobody (the swarm moved on beyond its 0.5 m range): it is back in the estimate at the
    pose estimated last before it was lost, its covariance grown by the rejoin prior's (correlated x-y included), kept
    at dead reckoning; the executor's command for it drives at most ``REJOIN_DRIVE_M`` a step."""
    traj = random_trajectory(4, 1, np.random.default_rng(7))
    cov = np.tile(np.array([[4e-4, 3e-4, 0.0], [3e-4, 4e-4, 0.0], [0.0, 0.0, 1e-3]]), (4, 1, 1))  # correlated x-y
    start = SwarmEstimate(traj.ids, traj.initial_poses.copy(), cov)
    result = RunResult("inchworm", traj, start, None, rejoined=[RejoinedRobot(3, 0, 0)])
    pose, last_cov = last_estimate(result, 3)
    assert np.array_equal(pose, traj.initial_poses[3]) and np.array_equal(last_cov, cov[3])
    others = start.select(np.array([True, True, True, False]))
    seen = Observations(np.array([0]), np.array([1]), np.array([0.3]), np.array([0.1]))  # nobody sees robot 3, nor it anyone
    located = localize_rejoined(make_localizer("paper", CFG), others, {}, seen, CFG, {3: (pose, last_cov)})
    row = int(np.flatnonzero(located.ids == 3)[0])
    prior = SwarmEstimate.isotropic([3], pose[None], 0.5, 0.5).cov[0]
    assert np.array_equal(located.ids, traj.ids) and np.allclose(located.poses[row], pose)
    assert np.allclose(located.cov[row], last_cov + prior)  # honest: its old uncertainty and the rejoin's
    poses = located.poses.copy()
    poses[row, :2] += 2.0  # estimated 2.8 m from its place: an agent refuses a drive beyond 1 m
    away = SwarmEstimate(located.ids, poses, located.cov)
    swarm = SimulatedSwarm(traj.ids, poses, CFG, 0)
    localizer = make_localizer("paper", CFG)
    executor = InchwormExecutor(swarm, localizer, make_strategy("inchworm", 4, CFG, localizer, FAST, 0), CFG)
    sent: list[StepCommands] = []
    execute = swarm.execute
    swarm.execute = lambda cmd: (sent.append(cmd), execute(cmd))[1]  # type: ignore[method-assign]  # record, then move
    executor._step(RunResult("inchworm", traj, away, None), 0, 0, np.ones(4, dtype=bool), away, traj)
    drives = sent[0].commands[:, 1]
    assert drives[row] == pytest.approx(REJOIN_DRIVE_M) and np.all(np.delete(drives, row) < REJOIN_DRIVE_M)
