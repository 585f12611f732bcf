"""Re-running a recorded run's coordinator decisions (``swarm replay --check``) and rebuilding it (``swarm plot``).

``load_recording(path)`` reads an MCAP recording (finished or not, ``runtime.recording.mcap_log``)
into a ``RecordedRun``: the run metadata and the decoded messages by step (estimates,
commands, observation reports, truths) and by configuration (plans); messages that do not
decode are counted and left out, channels outside ``swarm/`` (derived views such as
``/foxglove/...``) are ignored; a message repeated (a re-sent command or request) is kept once.

``check(recorded, ...)`` re-runs, in the order the coordinator ran them,

* the initial estimate (step 0) from the seed and the trajectory, when the metadata has them,
* the anchor selection of every configuration (``make_strategy(method, n, cfg, localizer,
  selection, seed).plan(estimate before the configuration, desired)`` through ``clear_plan`` (bodies); the strategy is seeded
  and stateful, so plans are re-run in order and stop at the first one whose input is missing),
* every step's localization: ``localize_observable(make_localizer(localizer, cfg), estimate of
  step - 1, the step's MotionCommands, the step's ObservationReports in id order, cfg)``, for the
  robots of the step's recorded estimate (lost ones dropped), and after robots rejoined
  ``executor.localize_rejoined``; the estimate of step - 1 is the one the check recomputed, carried
  from step 0 on with whatever the localizer keeps in it beyond the recorded 3x3 covariances (``_Chain``),

and compares each result with the recorded message. On the floating-point platform the run was
recorded on (``runtime.recording.mcap_log.float_platform``, in the metadata's versions) the
comparison is exact (float equality, no tolerance); elsewhere, or for recordings that do not say,
values may differ in their last bits (numpy's SIMD paths, BLAS kernels), so they must agree to
``CROSS_PLATFORM_RTOL`` relative (plus ``CROSS_PLATFORM_ATOL`` absolute, for values near zero) and
the result says the check was not exact. It stops at the first divergence. ``rebuild_run(recorded)`` turns a recording into the
executor's ``RunResult`` (for the plots of ``swarm sim``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, cast

import numpy as np

from coordinator.checkpoint import carried_fields
from coordinator.clearance import Regrouping
from coordinator.executor import among, localize_rejoined, rejoin_priors
from coordinator.legs import LegRecord, after_step, first_leg, next_leg
from coordinator.localization import Localizer, make_localizer
from coordinator.localization.partial import localize_observable
from coordinator.plan import Plan
from coordinator.run_result import ConfigRecord, RunResult, StepRecord
from coordinator.selection.genetic import GeneticConfig
from coordinator.selection.selector import SelectionConfig
from coordinator.simulate import initial_estimate
from coordinator.strategies import SelectedStrategy, Strategy, make_strategy
from runtime.errors import OptionError, SwarmInputError
from runtime.models.config import ModelConfig
from runtime.models.state import StepCommands, SwarmEstimate, index_of
from runtime.models.trajectory import Trajectory
from runtime.paths import StrPath
from runtime.recording.mcap_log import float_platform, read_messages, recording_info
from runtime.wire.keys import ROOT
from runtime.wire.messages import (
    EstimateMessage,
    MessageError,
    MotionCommand,
    ObservationReport,
    PlanMessage,
    TruthMessage,
    decode,
    observations_from_reports,
)


@dataclass
class RecordedRun:
    """What a recording holds, decoded; every dict is keyed by the global step (plans: by configuration, 1-based)."""

    path: Path
    info: dict[str, Any]
    meta: dict[str, Any]
    estimates: dict[int, EstimateMessage] = field(default_factory=dict)
    plans: dict[int, PlanMessage] = field(default_factory=dict)
    legs: dict[tuple[int, int], PlanMessage] = field(default_factory=dict)  # approach legs >= 1 by (configuration, leg)
    commands: dict[int, dict[int, MotionCommand]] = field(default_factory=dict)
    reports: dict[int, dict[int, ObservationReport]] = field(default_factory=dict)
    truths: dict[int, dict[int, TruthMessage]] = field(default_factory=dict)
    rejoins: dict[int, EstimateMessage] = field(default_factory=dict)  # a second estimate of a step: robots rejoined after it
    undecodable: int = 0
    messages: int = 0

    @property
    def complete(self) -> bool:
        return bool(self.info.get("complete"))

    def trajectory(self, override: Path | None = None) -> Trajectory:
        if override is not None:
            return Trajectory.load(override)
        data = self.meta.get("trajectory")
        if data is None:
            raise OptionError("trajectory", f"FILE must be given: {self.path} has no trajectory in its run metadata "
                                            "(swarm coordinator records it)")
        return Trajectory.from_json(data)

    def ids(self) -> np.ndarray:
        if 0 in self.estimates:
            return np.array(self.estimates[0].ids, dtype=np.int64)
        if "trajectory" in self.meta:
            return self.trajectory().ids
        raise SwarmInputError(f"{self.path}: no initial estimate (step 0) and no trajectory: the robots are unknown")


def load_recording(path: StrPath) -> RecordedRun:
    """Decode a recording (``SwarmInputError`` for files that are not readable MCAP recordings)."""
    path = Path(path)
    info = recording_info(path)  # validates the whole file first: a damaged file fails here, before anything is used
    meta = info["metadata"].get("run", {})
    rec = RecordedRun(path, info, meta if isinstance(meta, dict) else {})
    run = rec.meta.get("run")
    for topic, payload, _log, _pub in read_messages(path):
        if not topic.startswith(ROOT + "/"):
            continue  # derived views (e.g. /foxglove/...), not messages of the run
        rec.messages += 1
        try:
            msg = decode(payload, key=topic)
        except MessageError:
            rec.undecodable += 1
            continue
        if run is not None and msg.run != run:
            continue
        if isinstance(msg, EstimateMessage):
            first = rec.estimates.setdefault(msg.step, msg)
            if first.ids != msg.ids and set(first.ids) < set(msg.ids):
                rec.rejoins.setdefault(msg.step, msg)
        elif isinstance(msg, PlanMessage) and msg.leg:
            rec.legs.setdefault((msg.config, msg.leg), msg)
        elif isinstance(msg, PlanMessage):
            rec.plans.setdefault(msg.config, msg)
        elif isinstance(msg, MotionCommand):
            rec.commands.setdefault(msg.step, {}).setdefault(msg.robot, msg)
        elif isinstance(msg, ObservationReport):
            rec.reports.setdefault(msg.step, {}).setdefault(msg.robot, msg)
        elif isinstance(msg, TruthMessage):
            rec.truths.setdefault(msg.step, {}).setdefault(msg.robot, msg)
    return rec


# ------------------------------------------------------------------ configuration


MODEL_FIELDS = tuple(f for f in ModelConfig.__dataclass_fields__)


def recorded_model(rec: RecordedRun, overrides: dict[str, float] | None = None) -> ModelConfig:
    """The run's ``ModelConfig`` from the metadata (defaults where absent), fields in ``overrides`` replaced."""
    stored = rec.meta.get("model") or {}
    values = {k: float(v) for k, v in stored.items() if k in MODEL_FIELDS} if isinstance(stored, dict) else {}
    values.setdefault("robot_radius_m", 0.0)  # recorded before bodies: point robots
    values.update(overrides or {})
    return ModelConfig(**values)


def recorded_selection(rec: RecordedRun, overrides: dict[str, Any] | None = None) -> SelectionConfig:
    """The run's ``SelectionConfig`` from the metadata (defaults where absent), with ``overrides``
    (``w_v`` (w_l = 1 - w_v), ``samples``, ``population``, ``generations``, ``selection`` (the ranking method), ``mc_start``, ``mc_emax``)."""
    stored = rec.meta.get("selection") or {}
    stored = dict(stored) if isinstance(stored, dict) else {}
    stored.setdefault("mc_start", "estimate")  # recordings made before the Monte Carlo readings were options
    stored.setdefault("mc_emax", "mean")
    stored.setdefault("final_looks", 1)  # recordings made before the sequential final check: one fixed set
    genetic_stored = dict(stored.pop("genetic", {}) or {})
    genetic_stored.setdefault("screened", 0)  # ... and before the search screened its plans by prediction
    genetic = GeneticConfig(**genetic_stored)
    counts = stored.pop("anchor_counts", None)
    known = set(SelectionConfig.__dataclass_fields__) - {"genetic", "anchor_counts"}
    sel = SelectionConfig(**{k: v for k, v in stored.items() if k in known}, genetic=genetic,
                          anchor_counts=None if counts is None else tuple(int(c) for c in counts))
    o = overrides or {}
    if "w_v" in o:
        sel = replace(sel, w_v=o["w_v"], w_l=1.0 - o["w_v"])
    if "samples" in o:
        sel = replace(sel, samples=o["samples"])
    if "selection" in o:
        sel = replace(sel, method=o["selection"])
    if "mc_start" in o or "mc_emax" in o:
        sel = replace(sel, mc_start=o.get("mc_start", sel.mc_start), mc_emax=o.get("mc_emax", sel.mc_emax))
    if "population" in o or "generations" in o:
        sel = replace(sel, genetic=replace(sel.genetic, population=o.get("population", sel.genetic.population),
                                           generations=o.get("generations", sel.genetic.generations)))
    return sel


# ------------------------------------------------------------------ check


@dataclass
class Divergence:
    step: int
    what: str  # "estimate", "plan", "initial estimate"
    robot: int | None
    field: str
    recorded: Any
    recomputed: Any

    def __str__(self) -> str:
        who = f", robot {self.robot}" if self.robot is not None else ""
        return (f"divergence at step {self.step} ({self.what}{who}), {self.field}: "
                f"recorded {self.recorded!r} vs recomputed {self.recomputed!r}")


@dataclass
class CheckResult:
    estimates: int = 0
    plans: int = 0
    skipped: list[str] = field(default_factory=list)
    divergence: Divergence | None = None
    settings: dict[str, Any] = field(default_factory=dict)
    exact: bool = True  # False: recorded on another floating-point platform, compared to CROSS_PLATFORM_RTOL

    @property
    def passed(self) -> bool:
        return self.divergence is None


_AXES = ("x", "y", "heading")
CROSS_PLATFORM_RTOL = 1e-9  # relative agreement required between floating-point platforms
CROSS_PLATFORM_ATOL = 1e-15  # absolute, for values near zero (metres, radians and their squares)


def _differs(r: float, c: float, exact: bool) -> bool:
    if exact:
        return r != c or math.copysign(1, r) != math.copysign(1, c)
    return not abs(r - c) <= CROSS_PLATFORM_RTOL * max(abs(r), abs(c)) + CROSS_PLATFORM_ATOL


def compare_estimate(step: int, recorded: EstimateMessage, estimate: SwarmEstimate, what: str = "estimate",
                     exact: bool = True) -> Divergence | None:
    """The first robot and field where ``estimate`` differs from ``recorded`` (exactly, or to the cross-platform tolerance), or None."""
    got = EstimateMessage.from_estimate(estimate, run=recorded.run, step=step, stamp_ns=recorded.stamp_ns)
    if got.ids != recorded.ids:
        return Divergence(step, what, None, "ids", list(recorded.ids), list(got.ids))
    for k, robot in enumerate(recorded.ids):
        for a in range(3):
            r, c = recorded.poses[k][a], got.poses[k][a]
            if _differs(r, c, exact):
                return Divergence(step, what, robot, f"pose.{_AXES[a]}", r, c)
        for a in range(3):
            for b in range(3):
                r, c = recorded.cov[k][a][b], got.cov[k][a][b]
                if _differs(r, c, exact):
                    return Divergence(step, what, robot, f"cov[{a}][{b}]", r, c)
    return None


def same_float_platform(rec: RecordedRun) -> bool:
    """Whether ``rec`` was recorded on this floating-point platform (False when the recording does not say)."""
    versions = rec.meta.get("versions")
    return isinstance(versions, dict) and versions.get("float_platform") == float_platform()


def _plan_groups(plan: Plan, ids: np.ndarray) -> tuple[tuple[int, ...], ...]:
    return tuple(tuple(int(ids[k]) for k in group) for group in plan.groups)


def check(rec: RecordedRun, *, localizer: str | None = None, model: dict[str, float] | None = None,
          selection: dict[str, Any] | None = None, seed: int | None = None, method: str | None = None,
          trajectory: Path | None = None) -> CheckResult:
    """Re-run and compare (module doc); arguments given override the recorded settings."""
    localizer = localizer or rec.meta.get("localizer") or "paper"
    method = method or rec.meta.get("method")
    seed = seed if seed is not None else rec.meta.get("seed")
    cfg = recorded_model(rec, model)
    exact = same_float_platform(rec)
    result = CheckResult(settings={"localizer": localizer, "method": method, "seed": seed, "model": cfg.to_dict()}, exact=exact)
    if 0 not in rec.estimates:
        raise SwarmInputError(f"{rec.path}: no initial estimate (EstimateMessage of step 0): nothing to check")
    ids = np.array(rec.estimates[0].ids, dtype=np.int64)
    traj = None
    if trajectory is not None or "trajectory" in rec.meta:
        traj = rec.trajectory(trajectory)
        if not np.array_equal(traj.ids, ids):
            raise SwarmInputError(f"{rec.path}: trajectory robots {traj.ids.tolist()} differ from the estimate's {ids.tolist()}")
    loc = make_localizer(localizer, cfg)

    # step 0: the initial estimate, drawn from the seed
    if traj is not None and seed is not None and "initial_delta_m" in rec.meta:
        est0 = initial_estimate(traj, int(seed), float(rec.meta["initial_delta_m"]), float(rec.meta["initial_heading_sigma_rad"]))
        result.divergence = compare_estimate(0, rec.estimates[0], est0, "initial estimate", exact)
        if result.divergence:
            return result
        result.estimates += 1
    else:
        result.skipped.append("initial estimate (no seed, trajectory or initial uncertainty in the metadata)")
    chain = _Chain(rec, loc, cfg, exact, result)

    # plans, in configuration order (the seeded strategy is stateful)
    strategy = None
    if method is None or traj is None or seed is None:
        result.skipped.append("plans (no method, trajectory or seed in the metadata)")
    else:
        strategy = make_strategy(method, len(ids), cfg, loc, recorded_selection(rec, selection), int(seed))
    full, strategy_ids = strategy, ids
    plans_ok = strategy is not None
    plan_at_step = {p.step: p for p in rec.plans.values()}
    leg_at_step = {p.step: p for p in rec.legs.values()}
    legs: list[LegRecord] = []  # the approach legs of the configuration being checked, as recomputed
    track: _Change | None = None  # where its current leg's steps end (a touch may end one early)
    expected_config = 1

    last = max(rec.estimates)
    for step in range(0, last + 1):
        plan_msg = plan_at_step.get(step)
        if plan_msg is not None and plans_ok and strategy is not None and full is not None and traj is not None:  # plans_ok: all set
            before = chain.prior(step)
            if plan_msg.config != expected_config or before is None or plan_msg.config > len(traj.configurations):
                why = ("an earlier plan is not in the recording" if plan_msg.config != expected_config
                       else f"the trajectory has {len(traj.configurations)} configurations" if plan_msg.config > len(traj.configurations)
                       else chain.why(step) if step - 1 in rec.estimates else f"the estimate of step {step - 1} is not in the recording")
                result.skipped.append(f"plans from configuration {plan_msg.config} on ({why})")
                plans_ok = False
            else:
                planned = [r for group in plan_msg.groups for r in group]
                estimate = before.select(np.isin(before.ids, planned))  # a robot lost before the plan was made: dropped
                if not np.array_equal(estimate.ids, strategy_ids):  # robots lost or rejoined: as the executor does
                    strategy = _restricted(full, strategy, ids, strategy_ids, estimate.ids)
                    strategy_ids = estimate.ids
                desired = traj.configurations[plan_msg.config - 1][index_of(traj.ids, estimate.ids, "trajectory")]
                plan, regrouped, leg = first_leg(cfg, strategy.plan(estimate, desired)[0], estimate, desired)
                legs = [] if leg is None else [leg]
                track = _Change(plan_msg.config, plan, estimate.ids, regrouped, desired, step)
                groups = _plan_groups(plan, estimate.ids)
                if groups != plan_msg.groups:
                    result.divergence = Divergence(step, f"plan of configuration {plan_msg.config}", None, "groups",
                                                   [list(g) for g in plan_msg.groups], [list(g) for g in groups])
                    return result
                if plan.n_anchors != plan_msg.n_anchors:
                    result.divergence = Divergence(step, f"plan of configuration {plan_msg.config}", None, "n_anchors",
                                                   plan_msg.n_anchors, plan.n_anchors)
                    return result
                result.plans += 1
                expected_config += 1
        leg_msg = leg_at_step.get(step)
        if track is not None and plans_ok and step == track.end + 1 and track.touch and leg_msg is None:
            missing = track.missing_leg(cfg, legs, chain.prior(step), step)
            if missing is not None:
                result.divergence = missing
                return result
        if leg_msg is not None and plans_ok and traj is not None:
            before = chain.prior(step)
            lost = before is None or len(before.ids) < len(track.ids if track is not None else before.ids)
            if track is not None and leg_msg.config == track.config and leg_msg.step != track.end + 1 and not lost:
                result.divergence = Divergence(
                    step, f"approach leg {leg_msg.leg} of configuration {leg_msg.config}", None,
                    "first step (the leg before ends after its last group, or after a step that left two robots touching or its next step at risk)",
                    leg_msg.step, track.end + 1)
                return result
            divergence = _check_leg(leg_msg, step, legs, chain.prior(step), cfg, traj, expected_config - 1)
            if isinstance(divergence, Divergence):
                result.divergence = divergence
                return result
            if divergence is None:
                result.skipped.append(f"approach legs of configuration {leg_msg.config} from leg {leg_msg.leg} on "
                                      "(the plan or the estimate before it was not checked)")
                plans_ok = False
            else:
                legs.append(divergence)
                result.plans += 1
                if track is not None:
                    track.start, track.plan, track.touch, track.groups_run = step, divergence.plan, None, None
        if step == 0 or step not in rec.estimates:
            continue
        before = chain.prior(step)
        stood = sorted(set(rec.commands.get(step, {})) & set(legs[-1].deferred.tolist())) if legs and track is not None else []
        if stood and plans_ok and track is not None and track.start <= step <= track.end:
            result.divergence = Divergence(step, f"step {step} of configuration {track.config}", None,
                                           "robots commanded (a robot whose step was at risk stands in it: deferred_movers)",
                                           sorted(rec.commands.get(step, {})), sorted(set(rec.commands.get(step, {})) - set(stood)))
            return result
        if chain.localize(step, ids):
            return result
        if track is not None and plans_ok and cfg.robot_radius_m > 0 and track.start <= step <= track.end:
            after = chain.prior(step + 1)  # recomputed, or recorded where that is all there is to carry
            if before is None or after is None:  # the chain broke (a localizer's carried state): no later leg is
                track = None                      # checkable either, and the plans and legs say so when they come
            else:
                legs = track.after_step(cfg, legs, step, before, after, sorted(rec.commands.get(step, {})))
        if chain.rejoin(step):
            return result
    if chain.gaps:
        result.skipped.append(chain.gaps_text())
    return result


@dataclass
class _Change:
    """The configuration change being checked (``config`` 1-based): its strategy's ``plan`` cleared for bodies (rows of
    ``ids``), how it was split (``regrouped``), the ``desired`` positions (rows of ``ids``), and of its current leg (the
    plan, for a change without legs) the first step ``start`` and the ``plan``; ``touch`` says why that leg ended
    before its planned end (``coordinator.legs.after_step``), None while it did not."""

    config: int
    first: Plan
    ids: np.ndarray
    regrouped: Regrouping | None
    desired: np.ndarray
    start: int
    plan: Plan | None = None
    touch: str | None = None
    groups_run: int | None = None

    def __post_init__(self) -> None:
        self.plan = self.first if self.plan is None else self.plan

    @property
    def end(self) -> int:
        """The last step of the current leg: its plan's last, or the step a touch ended it at."""
        assert self.plan is not None
        return self.start + (self.plan.n_steps if self.groups_run is None else self.groups_run) - 1

    def after_step(self, cfg: ModelConfig, legs: list[LegRecord], step: int, before: SwarmEstimate, after: SwarmEstimate,
                   moved: list[int]) -> list[LegRecord]:
        """The change's legs after ``step`` as the executor has them (``coordinator.legs.after_step``; a change without
        legs as a first leg to the desired positions); where the leg ended there, ``touch`` says why."""
        assert self.plan is not None
        leg = legs[-1] if legs else LegRecord(self.first, self.ids, np.asarray(self.desired, float)[:, :2],
                                              np.zeros(len(self.ids), bool), self.regrouped)
        out, why = after_step(cfg, tuple(legs), leg, step - self.start, before, after, np.array(moved, np.int64))
        if why is not None:
            self.touch, self.groups_run = why, out[-1].groups_run
        return list(out)

    def missing_leg(self, cfg: ModelConfig, legs: list[LegRecord], before: SwarmEstimate | None, step: int) -> Divergence | None:
        """After a touch ended a leg at ``step`` - 1, the recording has no leg from ``step``: the divergence if the
        executor would have planned one (``next_leg`` from ``before``, the estimate after step - 1), else None."""
        if before is None:
            return None
        desired = self.desired[np.isin(self.ids, before.ids)]
        leg = next_leg(cfg, tuple(legs), before, desired, len(legs))
        if leg is None:
            return None
        return Divergence(step, f"approach leg {len(legs)} of configuration {self.config}", None,
                          f"groups (step {step - 1} left {self.touch}: the leg ends there and the next starts)",
                          [], [list(g) for g in _plan_groups(leg.plan, leg.ids)])


def _check_leg(msg: PlanMessage, step: int, legs: list[LegRecord], before: SwarmEstimate | None, cfg: ModelConfig,
               traj: Trajectory, config: int) -> LegRecord | Divergence | None:
    """Approach leg ``msg.leg`` of configuration ``msg.config`` (1-based) recomputed from ``before`` (the estimate after
    step - 1) as the executor does (``coordinator.legs.next_leg``) and compared with ``msg``: the leg, the divergence, or
    None when it cannot be checked (its configuration's plan or earlier legs were not, or no estimate before it)."""
    if before is None or msg.config != config or len(legs) != msg.leg:
        return None
    desired = traj.configurations[msg.config - 1][index_of(traj.ids, before.ids, "trajectory")]
    leg = next_leg(cfg, tuple(legs), before, desired, msg.leg)
    where = f"approach leg {msg.leg} of configuration {msg.config}"
    if leg is None:
        return Divergence(step, where, None, "groups", [list(g) for g in msg.groups], [])
    groups = _plan_groups(leg.plan, leg.ids)
    if groups != msg.groups:
        return Divergence(step, where, None, "groups", [list(g) for g in msg.groups], [list(g) for g in groups])
    if leg.n_anchors(len(before.ids)) != msg.n_anchors:
        return Divergence(step, where, None, "n_anchors", msg.n_anchors, leg.n_anchors(len(before.ids)))
    return leg


class _Chain:
    """The estimates the check recomputes, each the prior of the next step as in the run.

    A localizer may carry state from one step to the next in its ``SwarmEstimate`` beyond what an
    ``EstimateMessage`` holds (``checkpoint.carried_fields``: the joint localizer's joint covariance,
    (3n, 3n), not recorded: 18 MB a step for 500 robots). The check carries it itself: every step is
    localized from the estimate it recomputed for the step before (which, compared equal to the
    recorded one, is the coordinator's), from step 0 on, through lost robots (marginalised, as the
    executor drops them) and rejoined ones (``executor.localize_rejoined``, which starts again from
    poses and 3x3 covariances). Where the chain breaks (a step the recording cannot support) the
    recorded estimate is the next prior: exact for a localizer that carries nothing more; for one that
    does, the steps up to the next rejoin are not checked and ``gaps`` says why.
    """

    def __init__(self, rec: RecordedRun, loc: Localizer, cfg: ModelConfig, exact: bool, result: CheckResult) -> None:
        self.rec, self.loc, self.cfg, self.exact, self.result = rec, loc, cfg, exact, result
        self.estimate: SwarmEstimate = rec.estimates[0].to_estimate()  # step 0 carries nothing more (a drawn estimate)
        self.at = 0  # the step ``estimate`` is of
        self.broken: dict[int, str] = {}  # step -> why the chain broke there
        self.gaps: list[int] = []  # steps not checked because the chain broke before them

    def prior(self, step: int) -> SwarmEstimate | None:
        """The estimate after step ``step - 1``: the recomputed one, else the recorded one when that is all there is
        to carry, else None."""
        if self.at == step - 1:
            return self.estimate
        msg = self.rec.estimates.get(step - 1)
        if msg is None or carried_fields(self.estimate):
            return None
        return msg.to_estimate()

    def why(self, step: int) -> str:
        """Why there is no prior for ``step`` although the recording holds the estimate of the step before."""
        broke = max((s for s in self.broken if s < step), default=None)
        where = f" at step {broke} ({self.broken[broke]})" if broke is not None else ""
        return (f"the {self.loc.name} localizer carries {', '.join(carried_fields(self.estimate))} from step to step, "
                f"which the recording does not hold, and the recomputed chain broke{where}")

    def _break(self, step: int, why: str) -> None:
        self.broken.setdefault(step, why)
        self.result.skipped.append(f"step {step} ({why})")

    def localize(self, step: int, all_ids: np.ndarray) -> bool:
        """Localize ``step`` and compare; True at a divergence (in ``result``)."""
        rec = self.rec
        prior = self.prior(step)
        commands, reports = rec.commands.get(step, {}), rec.reports.get(step, {})
        if prior is None:
            if step - 1 in rec.estimates:
                self.gaps.append(step)
            else:
                self._break(step, "no estimate of the previous step")
            return False
        recorded = rec.estimates[step]
        index = {int(r): k for k, r in enumerate(all_ids)}
        unknown = sorted(set(commands) - set(index))
        if unknown:
            raise SwarmInputError(f"{rec.path}: step {step} has commands for robots {unknown} outside the run")
        ids = np.array(recorded.ids, dtype=np.int64)
        keep = np.isin(prior.ids, ids)
        missing = [int(r) for r in ids if r not in reports]
        why = ("no motion command" if not commands else f"no observation report from robots {missing}" if missing
               else "robots not in the previous estimate" if not np.array_equal(prior.ids[keep], ids) else None)
        if why is not None:
            self._break(step, why)
            return False
        prior = prior if keep.all() else prior.select(keep)  # robots lost during the step: as the executor drops them
        moving = np.isin(ids, list(commands))
        cmds = np.zeros((len(ids), 2))
        for k in np.flatnonzero(moving):
            cmd = commands[int(ids[k])]
            cmds[k] = (cmd.turn_rad, cmd.drive_m)
        obs = among(observations_from_reports(reports[int(r)] for r in ids), ids)
        estimate, _excluded = localize_observable(self.loc, prior, StepCommands(ids, cmds, moving), obs, self.cfg)
        self.result.divergence = compare_estimate(step, recorded, estimate, exact=self.exact)
        if self.result.divergence:
            return True
        self.result.estimates += 1
        self.estimate, self.at = estimate, step
        return False

    def rejoin(self, step: int) -> bool:
        """Robots that rejoined after ``step`` (a second estimate of that step): re-localize and compare; True at a
        divergence. Their estimate starts from poses and 3x3 covariances, so a broken chain is whole again."""
        recorded = self.rec.rejoins.get(step)
        if recorded is None:
            return False
        base = self.estimate if self.at == step else self.rec.estimates[step].to_estimate()
        ids = np.array(recorded.ids, dtype=np.int64)
        joined = [int(r) for r in ids if r not in set(base.ids.tolist())]
        reports = self.rec.reports.get(step, {})
        if not joined or any(r not in reports for r in joined):
            self._break(step, f"robots {joined} rejoined without their observation reports in the recording")
            return False
        stay = base.select(np.isin(base.ids, ids))
        obs = observations_from_reports(reports[r] for r in joined)
        priors = rejoin_priors(joined, obs, stay)
        reckoned = {r: self.last_estimate(r, step) for r in joined if r not in priors}  # out of range: where it was lost
        if any(v is None for v in reckoned.values()):
            self._break(step, f"robots {joined} rejoined without an earlier estimate of them in the recording")
            return False
        estimate = localize_rejoined(self.loc, stay, {r: priors[r] for r in joined if r in priors}, obs, self.cfg,
                                     {r: v for r, v in reckoned.items() if v is not None})
        self.result.divergence = compare_estimate(step, recorded, estimate, "estimate after robots rejoined", self.exact)
        if self.result.divergence:
            return True
        self.result.estimates += 1
        self.estimate, self.at = estimate, step
        return False

    def last_estimate(self, robot: int, step: int) -> tuple[np.ndarray, np.ndarray] | None:
        """``robot``'s pose and 3x3 covariance in the last recorded step estimate up to ``step`` that has it
        (``executor.last_estimate``), or None."""
        for s in sorted((s for s in self.rec.estimates if s <= step), reverse=True):
            est = self.rec.estimates[s]
            if robot in est.ids:
                e = est.to_estimate()
                row = int(np.flatnonzero(e.ids == robot)[0])
                return e.poses[row].copy(), e.cov[row].copy()
        return None

    def gaps_text(self) -> str:
        first, last = self.gaps[0], self.gaps[-1]
        steps = f"step {first}" if first == last else f"{len(self.gaps)} steps from {first} to {last}"
        return f"{steps} ({self.why(first)})"


def _restricted(full: Strategy, strategy: Strategy, all_ids: np.ndarray, strategy_ids: np.ndarray, ids: np.ndarray) -> Strategy:
    """The strategy for the robots ``ids``, as the executor has it: ``restrict`` when robots were lost, the whole
    swarm's strategy restricted to ``ids`` (its search's random stream where it was) when robots rejoined."""
    selector = getattr(strategy, "selector", None)
    calls = None if selector is None else selector.calls
    if np.isin(ids, strategy_ids).all():
        return strategy.restrict(np.isin(strategy_ids, ids))
    keep = np.isin(all_ids, ids)
    out = full if keep.all() else full.restrict(keep)
    if calls is not None:  # ``strategy`` has a selector, and so has the whole swarm's (the same method)
        cast(SelectedStrategy, out).selector.calls = calls
    return out


# ------------------------------------------------------------------ rebuild for plots


def rebuild_run(rec: RecordedRun, trajectory: Path | None = None) -> RunResult:
    """The executor's ``RunResult`` of the configurations the recording completed (estimate and plan of each).

    Truth (from ``TruthMessage``s) is attached when every robot's truth is recorded at step 0
    and after every completed configuration; otherwise the result has no truth.
    """
    traj = rec.trajectory(trajectory)
    ids = traj.ids
    if 0 not in rec.estimates:
        raise SwarmInputError(f"{rec.path}: no initial estimate (EstimateMessage of step 0): nothing to plot")
    index = {int(r): k for k, r in enumerate(ids)}

    def truth(step: int) -> np.ndarray | None:
        got = rec.truths.get(step, {})
        if not all(int(r) in got for r in ids):
            return None
        return np.array([got[int(r)].pose for r in ids], dtype=float)

    result = RunResult(rec.meta.get("method") or "recorded", traj, rec.estimates[0].to_estimate(), truth(0))
    have_truth = result.initial_truth is not None
    for config in sorted(rec.plans):
        msg = rec.plans[config]
        if config != len(result.configs) + 1 or config > len(traj.configurations):
            break
        order = [index[r] for group in msg.groups for r in group]
        if sorted(order) != list(range(len(ids))):
            raise SwarmInputError(f"{rec.path}: the plan of configuration {config} does not move every robot once")
        plan = Plan(np.array(order), tuple(len(g) for g in msg.groups))
        legs = _recorded_legs(rec, config, msg, ids)
        msgs = [msg, *(rec.legs[(config, k)] for k in range(1, len(legs)))]
        runs = _groups_run(msgs)
        groups = [g for m, n in zip(msgs, runs, strict=True) for g in m.groups[:n]]
        steps = [s for m, n in zip(msgs, runs, strict=True) for s in range(m.step, m.step + n)]
        if not all(s in rec.estimates for s in steps):
            break  # the recording ends inside this configuration
        records = []
        for k, s in enumerate(steps):
            moving = np.isin(ids, groups[k])
            cmds = np.zeros((len(ids), 2))
            for robot, cmd in rec.commands.get(s, {}).items():
                if robot in index:
                    cmds[index[robot]] = (cmd.turn_rad, cmd.drive_m)
            t = truth(s)
            have_truth = have_truth and (t is not None or k < len(steps) - 1)
            records.append(StepRecord(config - 1, k, moving, cmds, rec.estimates[s].to_estimate(), t, None))
        result.steps.extend(records)
        result.configs.append(ConfigRecord(config - 1, plan, None, records[-1].estimate, records[-1].truth, legs=legs))
    if not result.configs:
        raise SwarmInputError(f"{rec.path}: the recording holds no completed configuration (plan and estimates of all its steps)")
    if not have_truth:
        result.initial_truth = None
    return result


def _recorded_legs(rec: RecordedRun, config: int, msg: PlanMessage, ids: np.ndarray) -> tuple[LegRecord, ...]:
    """The approach legs of configuration ``config`` (1-based) as recorded: its plan ``msg`` and its ``PlanMessage``s
    of legs 1, 2, ... (each leg's staged robots are those of the next; its targets are not recorded: NaN); () without legs."""
    msgs = [msg]
    while (config, len(msgs)) in rec.legs:
        msgs.append(rec.legs[(config, len(msgs))])
    if len(msgs) == 1:
        return ()
    out = []
    for k, (m, run) in enumerate(zip(msgs, _groups_run(msgs), strict=True)):
        robots = np.array(sorted(r for g in m.groups for r in g), dtype=np.int64) if k else ids
        order = np.searchsorted(robots, [r for g in m.groups for r in g])
        nxt = {r for g in msgs[k + 1].groups for r in g} if k + 1 < len(msgs) else set()
        out.append(LegRecord(Plan(order, tuple(len(g) for g in m.groups)), robots, np.full((len(robots), 2), np.nan),
                             np.isin(robots, list(nxt)), groups_run=None if run == len(m.groups) else run))
    return tuple(out)


def _groups_run(msgs: list[PlanMessage]) -> list[int]:
    """The groups each of a change's plan and leg messages ran: all, or up to the next leg's first step (a touch ended
    the leg there, ``coordinator.legs.new_touches``)."""
    ends = [m.step for m in msgs[1:]]
    return [len(m.groups) if k == len(ends) else max(0, min(len(m.groups), ends[k] - m.step)) for k, m in enumerate(msgs)]
