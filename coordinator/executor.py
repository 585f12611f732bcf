"""PTP inchworm execution (Section 3, Fig. 2-3).

For each desired configuration C_d: (i) the strategy selects the plan (n_a, R_a)*;
then for every step k: (ii/v) body-frame commands for the step's mobile robots are
computed from the latest estimate, (iii) only those robots move, (iv) the swarm is
re-localized from the new observations; after the last step C_c = the estimate.
The executor talks to the robots only through a ``SwarmBackend``.

If some robots cannot be localized after a step (unobserved, or cut off from the rest),
the largest observable group is localized and those robots keep their dead-reckoning
estimate; the step record names them and says why.

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
from runtime.config import ModelConfig
from runtime.errors import SwarmInputError
from runtime.metrics import localization_error, trajectory_following_performance
from runtime.motion import command_towards
from runtime.state import StepCommands, SwarmEstimate
from runtime.trajectory import Trajectory


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
class ConfigRecord:
    config: int
    plan: Plan
    selection: Selection | None
    estimate: SwarmEstimate
    truth: np.ndarray | None


@dataclass
class RunResult:
    """Everything a run produced; positions in metres."""

    method: str
    trajectory: Trajectory
    initial_estimate: SwarmEstimate
    initial_truth: np.ndarray | None
    steps: list[StepRecord] = field(default_factory=list)
    configs: list[ConfigRecord] = field(default_factory=list)

    @property
    def has_truth(self) -> bool:
        return self.initial_truth is not None

    def true_configurations(self) -> np.ndarray:
        """(k + 1, n, 2): the true start, then the truth after each completed configuration."""
        return np.stack([self.initial_truth[:, :2], *[c.truth[:, :2] for c in self.configs]])

    def estimated_configurations(self) -> np.ndarray:
        return np.stack([self.initial_estimate.positions, *[c.estimate.positions for c in self.configs]])

    def localization_errors(self) -> np.ndarray:
        """e_l (Eq. 8) after each configuration (m)."""
        return localization_error(self.true_configurations()[1:], self.estimated_configurations()[1:])

    def following_errors(self) -> np.ndarray:
        """Mean |true - desired| after each configuration (m)."""
        k = len(self.configs)
        return localization_error(self.true_configurations()[1:], self.trajectory.configurations[:k])

    def travelled(self) -> np.ndarray:
        """Average total motion after each configuration (m), the partial sums of Eq. 25."""
        return np.cumsum(np.mean(np.linalg.norm(np.diff(self.true_configurations(), axis=0), axis=-1), axis=-1))

    def pf(self) -> float:
        """P_f (Eq. 24) at the last completed configuration."""
        truths = self.true_configurations()
        k = len(self.configs)
        return float(trajectory_following_performance(truths[-1], self.trajectory.configurations[k - 1], truths))

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
    """Follows a trajectory with a strategy, a localizer and a backend."""

    def __init__(
        self,
        backend: SwarmBackend,
        localizer: Localizer,
        strategy: Strategy,
        cfg: ModelConfig,
        progress: Callable[[int, int], None] | None = None,
        listener: ExecutorListener | None = None,
    ) -> None:
        self.backend = backend
        self.localizer = localizer
        self.strategy = strategy
        self.cfg = cfg
        self.progress = progress
        self.listener = listener

    def run(self, trajectory: Trajectory, initial_estimate: SwarmEstimate) -> RunResult:
        if not np.array_equal(trajectory.ids, self.backend.ids) or not np.array_equal(initial_estimate.ids, trajectory.ids):
            raise SwarmInputError(
                f"trajectory robots {trajectory.ids.tolist()}, backend robots {self.backend.ids.tolist()} "
                f"and estimate robots {initial_estimate.ids.tolist()} must be the same"
            )
        result = RunResult(self.strategy.name, trajectory, initial_estimate, self.backend.true_poses())
        estimate = initial_estimate
        total = len(trajectory.configurations)
        if self.listener is not None:
            self.listener.on_estimate(0, initial_estimate)
        for c, desired in enumerate(trajectory.configurations):
            plan, selection = self.strategy.plan(estimate, desired)  # (i)
            if self.listener is not None:
                self.listener.on_plan(c, len(result.steps) + 1, plan, selection)
            for k in range(plan.n_steps):
                estimate = self._step(result, c, k, plan.moving(k), estimate, desired)  # (ii)-(v)
            result.configs.append(ConfigRecord(c, plan, selection, estimate, self.backend.true_poses()))
            if self.progress:
                self.progress(c + 1, total)
        return result

    def _step(
        self, result: RunResult, config: int, step: int, moving: np.ndarray, estimate: SwarmEstimate, desired: np.ndarray
    ) -> SwarmEstimate:
        commands = np.where(moving[:, None], command_towards(estimate.poses, desired), 0.0)
        cmd = StepCommands(estimate.ids, commands, moving)
        self.backend.execute(cmd)  # (iii)
        observations = self.backend.observe()
        new, excluded = localize_observable(self.localizer, estimate, cmd, observations, self.cfg)  # (iv)
        fallback = None
        if excluded:
            reasons = sorted(set(excluded.values()))
            fallback = f"dead reckoning kept for robots {sorted(excluded)} ({', '.join(reasons)})"
        result.steps.append(StepRecord(config, step, moving, commands, new, self.backend.true_poses(), fallback))
        if self.listener is not None:
            self.listener.on_estimate(len(result.steps), new)
        return new
