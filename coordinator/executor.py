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
robot it has lost, so the command round needs no check of its own), and after each plan. A lost robot
(the backend has already stopped it) is dropped from the swarm: from the estimate, the remaining steps of the current plan (its groups keep their
other robots), the strategy (``restrict``: Eq. 4 and the anchor counts on the remaining
swarm), the observations and the localization. A plan made while a robot was lost is
made again without it. ``on_lost="abort"``, or fewer than ``min_robots`` left, ends the
run with ``RunAborted`` instead. Metrics (e_l, following error, P_f) are over the robots
that finished.

Bodies (docs/bodies.md): with ``cfg.robot_radius_m`` > 0 every plan is checked before its
first command under the nominal motion of its steps; a step whose movers would come too
close to each other or to a still robot is split into sub-steps (``coordinator.clearance.clear_plan``),
so every strategy runs collision-free and the record says so (``ConfigRecord.regrouped``). A mover whose straight drive
would end too close to a neighbour for the bound drives in approach legs (``coordinator.legs``): to a staging point
first, then, after the swarm re-localized, on from there (``ConfigRecord.legs``); a step that leaves two robots touching
ends its leg there and the next is planned at once, and robots whose next step in the leg is at risk stand in it
and go on in the next (``coordinator.legs.after_step``, ``_touched``).
``RunResult.contacts`` finds where the true motion brought bodies into contact.

An optional ``ExecutorListener`` is told what the executor decided, without changing
what it does: ``on_estimate(0, initial)`` at the start, ``on_plan(c, first_step, plan,
selection)`` when configuration ``c`` (0-based) is planned, before its first command,
``on_leg(c, leg, first_step, record)`` (optional: called when the listener has it) before the first command of approach
leg ``leg`` >= 1 of configuration ``c`` (``coordinator.legs``), ``on_estimate(step, estimate)`` after every step and,
with ground truth and bodies,
``on_contacts(contacts)`` after a step in which true bodies touched. Steps are numbered globally over
the run, motion steps from 1 (docs/protocol.md), so the first step of configuration c
is 1 + the steps of all earlier configurations. A distributed backend uses it to
publish plans and estimates and to stamp its commands with their configuration; the
in-process runs pass none.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Protocol, cast

import numpy as np

from coordinator.backend import BackendEnded, SwarmBackend
from coordinator.checkpoint import RunState
from coordinator.clearance import Regrouping
from coordinator.legs import LEG_CAP, LegRecord, after_step, first_leg, next_leg
from coordinator.localization import Localizer
from coordinator.localization.partial import localize_observable
from coordinator.plan import Plan
from coordinator.run_result import ConfigRecord, ContactEvent, LostRobot, RejoinedRobot, RunResult, StepRecord, contact_events
from coordinator.selection.selector import Selection
from coordinator.strategies import Strategy
from runtime.errors import LocalizationError, SwarmInputError, SwarmRunError
from runtime.models.config import ModelConfig
from runtime.models.motion import command_towards
from runtime.models.state import Observations, StepCommands, SwarmEstimate, index_of
from runtime.models.trajectory import Trajectory

_log = logging.getLogger(__name__)
REJOIN_DELTA_M = 0.5  # position std (m) of a rejoining robot's prior around the pose its neighbours' observations give
REJOIN_HEADING_SIGMA = 0.5  # heading std (rad) of that prior
REJOIN_DRIVE_M = 0.5  # longest drive (m) of a step for a robot known only to REJOIN_DELTA_M / sqrt(2) or worse (half the
# agents' default limit, CommandLimits.max_drive_m: one far from its place gets there over several steps)


class RunAborted(SwarmRunError):
    """The run ended because robots were lost (``on_lost="abort"``, fewer than ``min_robots`` left, or the robots
    left cannot finish the trajectory); ``robots`` names every robot lost, ``result`` holds what was completed."""

    def __init__(self, message: str, robots: list[int], result: RunResult | None = None) -> None:
        super().__init__(message, robots)
        self.result = result


class ExecutorListener(Protocol):
    """Observer of a run (see the module doc); called on the executor's thread."""

    def on_plan(self, config_index: int, first_step: int, plan: Plan, selection: Selection | None) -> None:
        """Configuration ``config_index`` (0-based) is planned; its steps are ``first_step`` .. ``first_step + plan.n_steps - 1``
        (fewer where a touch ends it: the next approach leg's ``on_leg`` then follows the step that ended it)."""
        ...

    def on_estimate(self, step: int, estimate: SwarmEstimate) -> None:
        """The estimate after global step ``step`` (0: the initial estimate)."""
        ...

    def on_contacts(self, contacts: list[ContactEvent]) -> None:
        """The robots' true bodies touched during the step just made (ground truth and a body radius only; not called otherwise)."""
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
        on_checkpoint: Callable[[RunState], None] | None = None,
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
        self.on_checkpoint = on_checkpoint
        self._full_strategy = strategy  # for the whole swarm: a rejoining robot comes back into it
        self._executed = 0  # command rounds sent in the current run (the global step in progress)
        self.result: RunResult | None = None  # the run in progress (or last run): what it completed so far

    def run(self, trajectory: Trajectory, initial_estimate: SwarmEstimate, resume: RunState | None = None) -> RunResult:
        """Follow ``trajectory`` from ``initial_estimate``; with ``resume``, go on from that state of the same run
        (another coordinator's checkpoint: the backend's robots are the state's)."""
        start = initial_estimate if resume is None else resume.estimate
        if not np.array_equal(start.ids, self.backend.ids) or not np.isin(start.ids, trajectory.ids).all() or \
                not np.array_equal(initial_estimate.ids, trajectory.ids):
            raise SwarmInputError(
                f"trajectory robots {trajectory.ids.tolist()}, backend robots {self.backend.ids.tolist()} "
                f"and estimate robots {start.ids.tolist()} must be the same"
            )
        total = len(trajectory.configurations)
        if resume is None:
            result = self.result = RunResult(self.strategy.name, trajectory, initial_estimate, self.backend.true_poses())
            self._executed, estimate, first, group, plan, planned_ids = 0, initial_estimate, 0, 0, None, None
            regrouped: Regrouping | None = None
            if self.listener is not None:
                self.listener.on_estimate(0, initial_estimate)
            self._checkpoint(result, 0, 0, estimate, None, None)
        else:
            result, estimate, first, group = resume.result, resume.estimate, resume.config, resume.group
            plan, planned_ids, regrouped = resume.plan, resume.planned_ids, resume.regrouped
            self.result, self._executed = result, resume.step
            self._restore_strategy(trajectory.ids, estimate.ids, resume.selector_calls)
        try:
            self._follow(result, trajectory, estimate, first, group, plan, planned_ids, regrouped,
                         () if resume is None else resume.legs)
        except RunAborted as exc:
            exc.result = result  # the configurations completed before the end
            raise
        except BackendEnded:
            raise
        except (SwarmInputError, SwarmRunError, LocalizationError) as exc:
            if not result.lost:
                raise
            lost = sorted(r.robot for r in result.lost)
            raise RunAborted(f"after losing {_robot_list(lost)}, the robots left cannot go on after configuration "
                             f"{len(result.configs)} of {total}: {exc}", lost, result) from exc
        return result

    def _follow(self, result: RunResult, trajectory: Trajectory, estimate: SwarmEstimate, first: int, group: int,
                plan: Plan | None, planned_ids: np.ndarray | None, regrouped: Regrouping | None,
                legs: tuple[LegRecord, ...] = ()) -> None:
        """Configurations ``first``.. of ``trajectory`` (the first from group ``group`` of ``plan`` if given, in the last
        of its approach ``legs`` if any: ``plan`` is that leg's)."""
        total, selection = len(trajectory.configurations), None
        for c in range(first, total):
            if plan is None:
                estimate = self._rejoin(result, c, self._drop_lost(result, c, estimate)[0], trajectory.ids)
                estimate = self._drop_lost(result, c, estimate)[0]
                while True:  # (i), again if a robot was lost meanwhile
                    desired = self._desired(trajectory, c, estimate.ids)
                    plan, selection = self.strategy.plan(estimate, desired)
                    estimate, keep = self._drop_lost(result, c, estimate)
                    if keep is None:
                        break
                plan, regrouped, leg = first_leg(self.cfg, plan, estimate, desired)
                legs = () if leg is None else (leg,)
                if self.listener is not None:
                    self.listener.on_plan(c, len(result.steps) + 1, plan, selection)
                planned_ids, group = estimate.ids, 0
                self._checkpoint(result, c, 0, estimate, plan, planned_ids, regrouped, legs=legs)
            done = sum(leg.n_steps for leg in legs[:-1])  # steps of this configuration's earlier legs
            while True:
                assert plan is not None and planned_ids is not None  # set with the plan (and checkpointed with it)
                current = legs[-1] if legs else None
                for k in range(group, len(plan.groups) if current is None else current.n_steps):
                    estimate = self._drop_lost(result, c, estimate)[0]
                    moving = np.isin(estimate.ids, planned_ids[plan.groups[k]])
                    if legs:  # robots whose step was at risk stand (``LegRecord.deferred``)
                        moving &= ~np.isin(estimate.ids, legs[-1].deferred)
                    if moving.any():  # a group whose robots were all lost is skipped
                        before = estimate
                        estimate = self._step(result, c, done + k, moving, estimate, trajectory, current)  # (ii)-(v)
                        legs = self._touched(trajectory, c, legs, k, before, estimate, before.ids[moving], plan,
                                             planned_ids, regrouped)
                    self._checkpoint(result, c, k + 1, estimate, plan, planned_ids, regrouped, legs=legs)
                    if legs and legs[-1].n_steps == k + 1:  # the leg's last group, or a touch ended it
                        break
                if not legs or len(legs) >= LEG_CAP:  # next_leg: None when nobody goes on or needs a correction
                    break
                done += legs[-1].n_steps
                estimate = self._drop_lost(result, c, estimate)[0]
                leg = next_leg(self.cfg, legs, estimate, self._desired(trajectory, c, estimate.ids), len(legs))
                if leg is None:
                    break
                legs, plan, planned_ids, regrouped, group = (*legs, leg), leg.plan, leg.ids, leg.regrouped, 0
                on_leg = getattr(self.listener, "on_leg", None)
                if on_leg is not None:
                    on_leg(c, len(legs) - 1, len(result.steps) + 1, leg)
                self._checkpoint(result, c, 0, estimate, plan, planned_ids, regrouped, legs=legs)
            if legs:
                plan, planned_ids, regrouped = legs[0].plan, legs[0].ids, legs[0].regrouped
            result.configs.append(ConfigRecord(c, plan, selection, estimate, self.backend.true_poses(), planned_ids, regrouped, legs))
            plan, selection, regrouped, legs, group = None, None, None, (), 0
            if self.progress:
                self.progress(c + 1, total)
        self._checkpoint(result, total, 0, estimate, None, None, finished=True)

    def _touched(self, trajectory: Trajectory, config: int, legs: tuple[LegRecord, ...], k: int, before: SwarmEstimate,
                 after: SwarmEstimate, moved: np.ndarray, plan: Plan, planned_ids: np.ndarray,
                 regrouped: Regrouping | None) -> tuple[LegRecord, ...]:
        """The change's legs after group ``k`` of ``plan`` ran (``coordinator.legs.after_step``; a change without legs
        as a first leg to the desired positions), logged where the leg ended or robots stand in its next step."""
        leg = legs[-1] if legs else LegRecord(plan, planned_ids, np.asarray(self._desired(trajectory, config, planned_ids), float)[:, :2],
                                              np.zeros(len(planned_ids), bool), regrouped)
        out, why = after_step(self.cfg, legs, leg, k, before, after, moved)
        if why is not None:
            _log.info("configuration %d: after step %d (%s) the leg ends there", config + 1, self._executed, why)
        elif out and len(out[-1].deferred) > len(leg.deferred):
            _log.info("configuration %d: after step %d robots %s stand in the next step (at risk there): they go on in "
                      "the next leg", config + 1, self._executed, np.setdiff1d(out[-1].deferred, leg.deferred).tolist())
        return out

    def _checkpoint(self, result: RunResult, config: int, group: int, estimate: SwarmEstimate, plan: Plan | None,
                    planned_ids: np.ndarray | None, regrouped: Regrouping | None = None, finished: bool = False,
                    legs: tuple[LegRecord, ...] = ()) -> None:
        """Hand the run's state to ``on_checkpoint`` (after the start, each plan, each leg, each step and at the end)."""
        if self.on_checkpoint is not None:
            selector = getattr(self.strategy, "selector", None)
            self.on_checkpoint(RunState(self._executed, config, group, estimate, plan, planned_ids,
                                        0 if selector is None else selector.calls, result, finished, regrouped, legs=legs))

    def _restore_strategy(self, all_ids: np.ndarray, ids: np.ndarray, selector_calls: int) -> None:
        """The strategy for the robots ``ids`` of the swarm ``all_ids``, its search's random stream at
        ``selector_calls`` (a checkpoint's, or where it was before a robot rejoined)."""
        keep = np.isin(all_ids, ids)
        self.strategy = self._full_strategy if keep.all() else self._full_strategy.restrict(keep)
        selector = getattr(self.strategy, "selector", None)
        if selector is not None:
            selector.calls = selector_calls

    def _rejoin(self, result: RunResult, config: int, estimate: SwarmEstimate, all_ids: np.ndarray) -> SwarmEstimate:
        """Lost robots whose agents came back (``take_rejoining`` of the backend) rejoin before configuration
        ``config`` is planned: each is asked for its observations of the current step, gets a prior with a large
        covariance (``REJOIN_DELTA_M``, ``REJOIN_HEADING_SIGMA``) around the pose its observations of its
        neighbours' estimates give, and the swarm is localized again with them. One that sees fewer than two robots
        (the swarm moved on out of its sensing range) comes back at its last estimate before it was lost
        (``last_estimate``), its covariance grown by the same amounts: it is planned and commanded like the others,
        so dead reckoning drives it to its place in the configuration, among its neighbours, and the localizer fixes
        it once they observe each other (until then the step records name it as kept at dead reckoning, and it
        drives at most ``REJOIN_DRIVE_M`` a step). One that answers nothing stays lost."""
        take = getattr(self.backend, "take_rejoining", None)
        robots = take() if take is not None and self._executed > 0 else []
        if not robots:
            return estimate
        obs = self.backend.observe_rejoining(robots)  # type: ignore[attr-defined]  # with take_rejoining; a robot that does not answer is lost again
        priors = rejoin_priors(robots, obs, estimate)
        estimate = self._drop_lost(result, config, estimate)[0]  # those that did not answer
        joined = [r for r in sorted(robots) if r in self.backend.ids]
        if not joined:
            return estimate
        reckoned = {robot: last_estimate(result, robot) for robot in joined if robot not in priors}
        for robot in reckoned:
            seen = int(np.sum((obs.observer == robot) & np.isin(obs.observed, estimate.ids)))
            _log.warning("robot %d rejoins at its last estimate (it observes %d robot(s) of the run): dead reckoning "
                         "brings it among its neighbours", robot, seen)
        located = localize_rejoined(self.localizer, estimate, {r: priors[r] for r in joined if r in priors}, obs, self.cfg,
                                    reckoned)
        selector = getattr(self.strategy, "selector", None)
        self._restore_strategy(all_ids, located.ids, 0 if selector is None else selector.calls)
        for robot in joined:
            result.rejoined.append(RejoinedRobot(robot, self._executed, config))
        if self.listener is not None:
            self.listener.on_estimate(self._executed, located)
        return located

    @staticmethod
    def _desired(trajectory: Trajectory, config: int, ids: np.ndarray) -> np.ndarray:
        return cast(np.ndarray, trajectory.configurations[config][index_of(trajectory.ids, ids, "trajectory")])

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
            raise RunAborted(f"lost {names}; the policy for a lost robot is abort: the run ends", sorted(lost))
        if keep.sum() < self.min_robots:
            raise RunAborted(f"lost {names}; {int(keep.sum())} robots left, fewer than the minimum {self.min_robots}", sorted(lost))
        self.strategy = self.strategy.restrict(keep)
        return estimate.select(keep), keep

    def _step(
        self, result: RunResult, config: int, step: int, moving: np.ndarray, estimate: SwarmEstimate, trajectory: Trajectory,
        leg: LegRecord | None = None,
    ) -> SwarmEstimate:
        desired = self._desired(trajectory, config, estimate.ids)
        if leg is not None:  # an approach leg: its robots drive to its targets (a staging point or their desired position)
            there = np.isin(leg.ids, estimate.ids)
            desired[index_of(estimate.ids, leg.ids[there], "leg")] = leg.targets[there]
        commands = np.where(moving[:, None], command_towards(estimate.poses, desired), 0.0)
        unsure = estimate.cov[:, 0, 0] + estimate.cov[:, 1, 1] > REJOIN_DELTA_M**2 / 2  # a robot rejoining by dead reckoning
        commands[unsure, 1] = np.minimum(commands[unsure, 1], REJOIN_DRIVE_M)  # approaches in steps an agent accepts
        cmd = StepCommands(estimate.ids, commands, moving)
        self._executed += 1
        self.backend.execute(cmd)  # (iii)
        observations = self.backend.observe()  # robots lost during the command round are no longer asked
        estimate, keep = self._drop_lost(result, config, estimate)
        if keep is not None:
            cmd = cmd.select(keep)
        observations = among(observations, estimate.ids)
        new, excluded = localize_observable(self.localizer, estimate, cmd, observations, self.cfg)  # (iv)
        fallback = None
        if excluded:
            reasons = sorted(set(excluded.values()))
            fallback = f"dead reckoning kept for robots {sorted(excluded)} ({', '.join(reasons)})"
        last = result.steps[-1] if result.steps else None
        before = result.initial_truth if last is None else last.truth
        before_ids = trajectory.ids if last is None or last.truth_ids is None else last.truth_ids
        truth = self.backend.true_poses()
        truth_ids = None if truth is None or len(truth) == trajectory.n else np.array(self.backend.ids, dtype=np.int64)
        result.steps.append(StepRecord(config, step, cmd.moving, cmd.commands, new, truth, fallback, truth_ids))
        if self.listener is not None:
            self.listener.on_estimate(len(result.steps), new)
            if self.cfg.robot_radius_m > 0 and before is not None and truth is not None:
                contacts = contact_events(len(result.steps), result.steps[-1], before, before_ids, trajectory.ids, self.cfg.robot_radius_m)
                if contacts:
                    self.listener.on_contacts(contacts)
        return new


def _robot_list(ids: list[int]) -> str:
    return f"robot {ids[0]}" if len(ids) == 1 else f"robots {', '.join(map(str, ids))}"


def rejoin_priors(robots: list[int], obs: Observations, estimate: SwarmEstimate) -> dict[int, np.ndarray]:
    """The pose of each of ``robots`` that its observations ``obs`` of the robots of ``estimate`` give (those that saw
    fewer than two are left out: they stay lost)."""
    poses = {robot: _pose_from_neighbours(robot, obs, estimate) for robot in robots}
    return {robot: pose for robot, pose in poses.items() if pose is not None}


def last_estimate(result: RunResult, robot: int) -> tuple[np.ndarray, np.ndarray]:
    """The last pose estimated for ``robot`` before it was lost (the run's steps, else the initial estimate) and its
    3x3 covariance: where a rejoining robot that sees fewer than two robots comes back."""
    for est in [*(s.estimate for s in reversed(result.steps)), result.initial_estimate]:
        row = np.flatnonzero(est.ids == robot)
        if row.size:
            return est.poses[row[0]].copy(), est.cov[row[0]].copy()
    raise SwarmInputError(f"robot {robot} has no estimate in this run")


def localize_rejoined(localizer: Localizer, estimate: SwarmEstimate, priors: dict[int, np.ndarray], obs: Observations,
                      cfg: ModelConfig, reckoned: dict[int, tuple[np.ndarray, np.ndarray]] | None = None) -> SwarmEstimate:
    """The swarm of ``estimate`` with the robots of ``priors`` and ``reckoned`` back in it (ids sorted), localized
    again from the rejoining robots' observations ``obs``: each rejoining robot's prior is its pose from ``priors``
    with ``REJOIN_DELTA_M`` / ``REJOIN_HEADING_SIGMA``, or (one that saw fewer than two robots) its last estimate
    ``reckoned`` (pose, 3x3 covariance, ``last_estimate``) with the covariance grown by as much; the others' their
    estimate's poses and 3x3 covariances (what the estimate carries beyond them, e.g. a joint covariance, is not:
    the cross-covariances with the newcomers are unknown)."""
    grow = SwarmEstimate.isotropic([0], np.zeros((1, 3)), REJOIN_DELTA_M, REJOIN_HEADING_SIGMA).cov[0]
    rows = {**{r: (pose, grow) for r, pose in priors.items()}, **{r: (p, c + grow) for r, (p, c) in (reckoned or {}).items()}}
    joined = sorted(rows)
    new = SwarmEstimate(np.array(joined, dtype=np.int64), np.array([rows[r][0] for r in joined], dtype=float).reshape(-1, 3),
                        np.array([rows[r][1] for r in joined]).reshape(-1, 3, 3))
    ids = np.concatenate([estimate.ids, new.ids])
    order = np.argsort(ids, kind="stable")
    merged = SwarmEstimate(ids[order], np.concatenate([estimate.poses, new.poses])[order],
                           np.concatenate([estimate.cov, new.cov])[order])
    located, _ = localize_observable(localizer, merged, StepCommands.stationary(merged.ids), among(obs, merged.ids), cfg)
    return located


def _pose_from_neighbours(robot: int, obs: Observations, estimate: SwarmEstimate) -> np.ndarray | None:
    """The pose [x, y, heading] of ``robot`` that its range-bearing observations of robots of ``estimate`` give
    (the heading turning the body-frame offsets onto the world ones, least squares; the position their mean), or
    None if it saw fewer than two (one fixes no heading)."""
    mine = (obs.observer == robot) & np.isin(obs.observed, estimate.ids)
    if mine.sum() < 2:
        return None
    seen = estimate.positions[index_of(estimate.ids, obs.observed[mine], "rejoin")]
    body = obs.range_m[mine, None] * np.stack([np.cos(obs.bearing_rad[mine]), np.sin(obs.bearing_rad[mine])], axis=1)
    w, b = seen - seen.mean(axis=0), body - body.mean(axis=0)  # world = R(heading) body
    heading = float(np.arctan2(np.sum(b[:, 0] * w[:, 1] - b[:, 1] * w[:, 0]), np.sum(b[:, 0] * w[:, 0] + b[:, 1] * w[:, 1])))
    c, s = np.cos(heading), np.sin(heading)
    position = np.mean(seen - body @ np.array([[c, s], [-s, c]]), axis=0)
    return np.array([position[0], position[1], heading])


def among(obs: Observations, ids: np.ndarray) -> Observations:
    """The observations between robots of ``ids`` (a robot dropped from the run may still be seen by others)."""
    inside = np.isin(obs.observer, ids) & np.isin(obs.observed, ids)
    return obs if inside.all() else obs.select(inside)
