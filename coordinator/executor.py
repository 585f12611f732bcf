"""PTP inchworm execution (Section 3, Fig. 2-3).

For each desired configuration C_d: (i) the strategy selects the plan (n_a, R_a)*;
then for every step k: (ii/v) body-frame commands for the step's mobile robots are
computed from the latest estimate, (iii) only those robots move, (iv) the swarm is
re-localized from the new observations; after the last step C_c = the estimate.
The executor talks to the robots only through a ``SwarmBackend``.

If some robots cannot be localized after a step (unobserved, or cut off from the rest),
the largest observable group is localized and those robots keep their dead-reckoning
estimate; the step record names them and says why.

Lost robots (docs/failure-model.md): the executor asks the backend which robots it lost
(``take_lost``) before each step, after each step's observation round (a backend asks no
robot it has lost, so the command round needs no check of its own), and after each plan. A lost robot (the backend has already stopped it) is dropped from the
swarm: from the estimate, the remaining steps of the current plan (its groups keep their
other robots), the strategy (``restrict``: Eq. 4 and the anchor counts on the remaining
swarm), the observations and the localization. A plan made while a robot was lost is
made again without it. ``on_lost="abort"``, or fewer than ``min_robots`` left, ends the
run with ``RunAborted`` instead. Metrics (e_l, following error, P_f) are over the robots
that finished.

An optional ``ExecutorListener`` is told what the executor decided, without changing
what it does: ``on_estimate(0, initial)`` at the start, ``on_plan(c, first_step, plan,
selection)`` when configuration ``c`` (0-based) is planned, before its first command,
and ``on_estimate(step, estimate)`` after every step. Steps are numbered globally over
the run, motion steps from 1 (docs/protocol.md), so the first step of configuration c
is 1 + the steps of all earlier configurations. A distributed backend uses it to
publish plans and estimates and to stamp its commands with their configuration; the
in-process runs pass none.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from coordinator.backend import SwarmBackend
from coordinator.localization import Localizer
from coordinator.localization.partial import localize_observable
from coordinator.plan import Plan
from coordinator.selection.selector import Selection
from coordinator.strategies import Strategy
from runtime.models.config import ModelConfig
from runtime.errors import LocalizationError, SwarmInputError
from runtime.models.metrics import localization_error, trajectory_following_performance
from runtime.models.motion import command_towards
from runtime.models.state import Observations, StepCommands, SwarmEstimate, index_of
from runtime.models.trajectory import Trajectory


@dataclass(frozen=True)
class StepRecord:
    config: int  # index of the desired configuration (0-based)
    step: int
    moving: np.ndarray  # (n,) bool
    commands: np.ndarray  # (n, 2) turn rad, drive m
    estimate: SwarmEstimate
    truth: np.ndarray | None  # (n, 3)
    fallback: str | None  # why dead reckoning was kept, if it was


@dataclass(frozen=True)
class LostRobot:
    """A robot dropped from the run during or after global step ``step`` (0 = before any motion), in configuration ``config`` (0-based)."""

    robot: int
    step: int
    config: int
    reason: str


class RunAborted(SwarmInputError):
    """The run ended because robots were lost (``on_lost="abort"``, fewer than ``min_robots`` left, or the robots
    left cannot finish the trajectory); ``robots`` names every robot lost, ``result`` holds what was completed."""

    def __init__(self, message: str, robots: list[int], result: RunResult | None = None) -> None:
        super().__init__(message)
        self.robots = robots
        self.result = result


@dataclass(frozen=True)
class ConfigRecord:
    config: int
    plan: Plan
    selection: Selection | None
    estimate: SwarmEstimate
    truth: np.ndarray | None
    planned_ids: np.ndarray | None = None  # the robots the plan's indices refer to (None: ``estimate.ids``; differs after a loss)

    def anchor_ids(self, step: int = 0) -> np.ndarray:
        """Ids of the anchors of the plan's ``step`` (robots lost since are included)."""
        ids = self.estimate.ids if self.planned_ids is None else self.planned_ids
        return ids[~self.plan.moving(step)]


@dataclass
class RunResult:
    """Everything a run produced; positions in metres."""

    method: str
    trajectory: Trajectory
    initial_estimate: SwarmEstimate
    initial_truth: np.ndarray | None
    steps: list[StepRecord] = field(default_factory=list)
    configs: list[ConfigRecord] = field(default_factory=list)
    lost: list[LostRobot] = field(default_factory=list)

    @property
    def has_truth(self) -> bool:
        return self.initial_truth is not None

    @property
    def finished_ids(self) -> np.ndarray:
        """The robots still in the run at its end: every metric is computed over them."""
        return self.configs[-1].estimate.ids if self.configs else self.initial_estimate.ids

    def _rows(self, ids: np.ndarray) -> np.ndarray:
        """Rows of the finished robots in arrays ordered like ``ids``."""
        return index_of(ids, self.finished_ids, "run result")

    def true_configurations(self) -> np.ndarray:
        """(k + 1, n, 2): the true start, then the truth after each completed configuration (finished robots)."""
        start = self.initial_truth[self._rows(self.initial_estimate.ids), :2]
        return np.stack([start, *[c.truth[self._rows(c.estimate.ids), :2] for c in self.configs]])

    def estimated_configurations(self) -> np.ndarray:
        start = self.initial_estimate.positions[self._rows(self.initial_estimate.ids)]
        return np.stack([start, *[c.estimate.positions[self._rows(c.estimate.ids)] for c in self.configs]])

    def desired_configurations(self) -> np.ndarray:
        """(k, n, 2): the desired configurations reached so far (finished robots)."""
        return self.trajectory.configurations[: len(self.configs)][:, self._rows(self.trajectory.ids)]

    def localization_errors(self) -> np.ndarray:
        """e_l (Eq. 8) after each configuration (m)."""
        return localization_error(self.true_configurations()[1:], self.estimated_configurations()[1:])

    def following_errors(self) -> np.ndarray:
        """Mean |true - desired| after each configuration (m)."""
        return localization_error(self.true_configurations()[1:], self.desired_configurations())

    def travelled(self) -> np.ndarray:
        """Average total motion after each configuration (m), the partial sums of Eq. 25."""
        return np.cumsum(np.mean(np.linalg.norm(np.diff(self.true_configurations(), axis=0), axis=-1), axis=-1))

    def pf(self) -> float:
        """P_f (Eq. 24) at the last completed configuration, over the robots that finished."""
        truths = self.true_configurations()
        return float(trajectory_following_performance(truths[-1], self.desired_configurations()[-1], truths))

    def anchor_counts(self) -> np.ndarray:
        return np.array([c.plan.n_anchors for c in self.configs])

    def steps_per_config(self) -> np.ndarray:
        return np.array([c.plan.n_steps for c in self.configs])


class ExecutorListener(Protocol):
    """Observer of a run (see the module doc); called on the executor's thread."""

    def on_plan(self, config_index: int, first_step: int, plan: Plan, selection: Selection | None) -> None:
        """Configuration ``config_index`` (0-based) is planned; its steps are ``first_step`` .. ``first_step + plan.n_steps - 1``."""
        ...

    def on_estimate(self, step: int, estimate: SwarmEstimate) -> None:
        """The estimate after global step ``step`` (0: the initial estimate)."""
        ...


class InchwormExecutor:
    """Follows a trajectory with a strategy, a localizer and a backend.

    ``on_lost``: ``"continue"`` (drop lost robots and go on) or ``"abort"``; ``min_robots``:
    abort when fewer robots than this are left (at least 2: localization needs a pair).
    """

    def __init__(
        self,
        backend: SwarmBackend,
        localizer: Localizer,
        strategy: Strategy,
        cfg: ModelConfig,
        progress: Callable[[int, int], None] | None = None,
        listener: ExecutorListener | None = None,
        on_lost: str = "continue",
        min_robots: int = 2,
    ) -> None:
        if on_lost not in ("continue", "abort"):
            raise SwarmInputError(f"on_lost must be 'continue' or 'abort', got {on_lost!r}")
        if min_robots < 2:
            raise SwarmInputError(f"min_robots must be at least 2 (localization needs a pair), got {min_robots}")
        self.backend = backend
        self.localizer = localizer
        self.strategy = strategy
        self.cfg = cfg
        self.progress = progress
        self.listener = listener
        self.on_lost = on_lost
        self.min_robots = min_robots
        self._executed = 0  # command rounds sent in the current run (the global step in progress)
        self.result: RunResult | None = None  # the run in progress (or last run): what it completed so far

    def run(self, trajectory: Trajectory, initial_estimate: SwarmEstimate) -> RunResult:
        if not np.array_equal(trajectory.ids, self.backend.ids) or not np.array_equal(initial_estimate.ids, trajectory.ids):
            raise SwarmInputError(
                f"trajectory robots {trajectory.ids.tolist()}, backend robots {self.backend.ids.tolist()} "
                f"and estimate robots {initial_estimate.ids.tolist()} must be the same"
            )
        result = self.result = RunResult(self.strategy.name, trajectory, initial_estimate, self.backend.true_poses())
        self._executed = 0  # command rounds sent (the global step in progress)
        if self.listener is not None:
            self.listener.on_estimate(0, initial_estimate)
        try:
            self._run(result, trajectory, initial_estimate)
        except RunAborted as exc:
            exc.result = result  # the configurations completed before the end
            raise
        except (SwarmInputError, LocalizationError) as exc:
            if not result.lost:
                raise
            lost = sorted(r.robot for r in result.lost)
            raise RunAborted(f"after losing {_robot_list(lost)}, the robots left cannot go on after configuration "
                             f"{len(result.configs)} of {len(trajectory.configurations)}: {exc}", lost, result) from exc
        return result

    def _run(self, result: RunResult, trajectory: Trajectory, estimate: SwarmEstimate) -> None:
        total = len(trajectory.configurations)
        for c in range(total):
            estimate = self._drop_lost(result, c, estimate)[0]
            while True:  # (i), again if a robot was lost meanwhile
                desired = self._desired(trajectory, c, estimate.ids)
                plan, selection = self.strategy.plan(estimate, desired)
                estimate, keep = self._drop_lost(result, c, estimate)
                if keep is None:
                    break
            if self.listener is not None:
                self.listener.on_plan(c, len(result.steps) + 1, plan, selection)
            planned_ids = estimate.ids
            for k, group in enumerate(plan.groups):
                estimate = self._drop_lost(result, c, estimate)[0]
                moving = np.isin(estimate.ids, planned_ids[group])
                if moving.any():  # a group whose robots were all lost is skipped
                    estimate = self._step(result, c, k, moving, estimate, trajectory)  # (ii)-(v)
            result.configs.append(ConfigRecord(c, plan, selection, estimate, self.backend.true_poses(), planned_ids))
            if self.progress:
                self.progress(c + 1, total)

    @staticmethod
    def _desired(trajectory: Trajectory, config: int, ids: np.ndarray) -> np.ndarray:
        return trajectory.configurations[config][index_of(trajectory.ids, ids, "trajectory")]

    def _drop_lost(self, result: RunResult, config: int, estimate: SwarmEstimate) -> tuple[SwarmEstimate, np.ndarray | None]:
        """Drop the robots the backend lost since last asked; the estimate of the others and the
        mask of the robots kept (None when nobody was lost). Raises ``RunAborted`` per the policy."""
        lost = self.backend.take_lost()
        if not lost:
            return estimate, None
        for robot, reason in sorted(lost.items()):
            result.lost.append(LostRobot(int(robot), self._executed, config, reason))
        keep = ~np.isin(estimate.ids, list(lost))
        names = ", ".join(f"robot {r} ({reason})" for r, reason in sorted(lost.items()))
        if self.on_lost == "abort":
            raise RunAborted(f"lost {names}; --on-lost abort ends the run", sorted(lost))
        if keep.sum() < self.min_robots:
            raise RunAborted(f"lost {names}; {int(keep.sum())} robots left, fewer than the minimum {self.min_robots}", sorted(lost))
        self.strategy = self.strategy.restrict(keep)
        return estimate.select(keep), keep

    def _step(
        self, result: RunResult, config: int, step: int, moving: np.ndarray, estimate: SwarmEstimate, trajectory: Trajectory
    ) -> SwarmEstimate:
        desired = self._desired(trajectory, config, estimate.ids)
        commands = np.where(moving[:, None], command_towards(estimate.poses, desired), 0.0)
        cmd = StepCommands(estimate.ids, commands, moving)
        self._executed += 1
        self.backend.execute(cmd)  # (iii)
        observations = self.backend.observe()  # robots lost during the command round are no longer asked
        estimate, keep = self._drop_lost(result, config, estimate)
        if keep is not None:
            cmd = cmd.select(keep)
        observations = _among(observations, estimate.ids)
        new, excluded = localize_observable(self.localizer, estimate, cmd, observations, self.cfg)  # (iv)
        fallback = None
        if excluded:
            reasons = sorted(set(excluded.values()))
            fallback = f"dead reckoning kept for robots {sorted(excluded)} ({', '.join(reasons)})"
        result.steps.append(StepRecord(config, step, cmd.moving, cmd.commands, new, self.backend.true_poses(), fallback))
        if self.listener is not None:
            self.listener.on_estimate(len(result.steps), new)
        return new


def _robot_list(ids: list[int]) -> str:
    return f"robot {ids[0]}" if len(ids) == 1 else f"robots {', '.join(map(str, ids))}"


def _among(obs: Observations, ids: np.ndarray) -> Observations:
    """The observations between robots of ``ids`` (a robot dropped from the run may still be seen by others)."""
    inside = np.isin(obs.observer, ids) & np.isin(obs.observed, ids)
    return obs if inside.all() else obs.select(inside)
