"""What a run produced (``RunResult``) and its records: steps, configurations, lost and rejoined robots, contacts.

The executor (``coordinator.executor``) builds it, the checkpoint (``coordinator.checkpoint``) serializes it, and
every command and study reads it; it depends on neither of them. Positions in metres.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from coordinator.clearance import Regrouping
from coordinator.legs import LegRecord
from coordinator.plan import Plan
from coordinator.selection.selector import Selection
from runtime.models.bodies import step_contacts
from runtime.models.metrics import localization_error, trajectory_following_performance
from runtime.models.state import SwarmEstimate, index_of
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
    truth_ids: np.ndarray | None = None  # the robots of ``truth``'s rows (None: the trajectory's; fewer after a loss)


@dataclass(frozen=True)
class ContactEvent:
    """Robots ``a`` < ``b`` touched during global step ``step`` (from 1) of configuration ``config`` (0-based):
    their true centres came ``distance`` m apart, less than two radii, ``point`` (x, y) m midway between them."""

    step: int
    config: int
    a: int
    b: int
    distance: float
    point: tuple[float, float]


@dataclass(frozen=True)
class LostRobot:
    """A robot dropped from the run during or after global step ``step`` (0 = before any motion), in configuration ``config`` (0-based)."""

    robot: int
    step: int
    config: int
    reason: str


@dataclass(frozen=True)
class RejoinedRobot:
    """A lost robot whose agent came back, re-localized and back in the run before configuration ``config`` (0-based),
    after global step ``step``."""

    robot: int
    step: int
    config: int


@dataclass(frozen=True)
class ConfigRecord:
    config: int
    plan: Plan
    selection: Selection | None
    estimate: SwarmEstimate
    truth: np.ndarray | None
    planned_ids: np.ndarray | None = None  # the robots the plan's indices refer to (None: ``estimate.ids``; differs after a loss)
    regrouped: Regrouping | None = None  # how the body constraint split the strategy's plan (None: it was clear)
    legs: tuple[LegRecord, ...] = ()  # approach legs (coordinator.legs; the first's plan is ``plan``), () when every robot drove straight

    @property
    def n_steps(self) -> int:
        """Steps taken: the plan's, or its approach legs' (each the steps it ran: a touch may end one early)."""
        return sum(leg.n_steps for leg in self.legs) if self.legs else self.plan.n_steps

    @property
    def planned_steps(self) -> int:
        """Steps of the strategy's plan, before the body constraint split it or added legs."""
        return self.plan.n_steps if self.regrouped is None else self.regrouped.planned_steps

    @property
    def staging_stops(self) -> int:
        """Approach legs driven to a staging point (one per robot and stop; not where a touch ended the leg before the
        robot's group)."""
        return int(sum(int((leg.staged & leg.ran).sum()) for leg in self.legs))

    @property
    def deferred(self) -> int:
        """Robots that stood in their step of a leg because it was at risk (one per robot and leg,
        ``coordinator.legs.deferred_movers``)."""
        return sum(len(leg.deferred) for leg in self.legs)

    @property
    def legs_cut(self) -> int:
        """Approach legs that ended before their last group: a step left two robots touching (``coordinator.legs.new_touches``)
        or the next step was at risk for all its robots (``deferred_movers``)."""
        return sum(leg.cut for leg in self.legs)

    @property
    def holds(self) -> int:
        """Approach legs a robot waited where it stood for a neighbour (one per robot and leg, ``coordinator.legs``)."""
        return int(sum(len(leg.held) for leg in self.legs))

    @property
    def corrections(self) -> int:
        """Approach legs a robot drove as a correction (one per robot and leg, ``coordinator.legs.corrections``): in a
        leg after the first without having gone on from the leg before (it had arrived, or stood, at risk)."""
        return int(sum(len(np.setdiff1d(leg.ids, before.going_on)) for before, leg in zip(self.legs, self.legs[1:], strict=False)))

    def anchor_ids(self, step: int = 0) -> np.ndarray:
        """Ids of the anchors of the plan's ``step`` (robots lost since are included)."""
        ids = self.estimate.ids if self.planned_ids is None else self.planned_ids
        return np.asarray(ids[~self.plan.moving(step)])


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
    rejoined: list[RejoinedRobot] = field(default_factory=list)
    world_events: list[tuple[int, Any]] = field(default_factory=list)  # a physical world's (global step, Contact | Stuck)

    @property
    def has_truth(self) -> bool:
        return self.initial_truth is not None

    @property
    def finished_ids(self) -> np.ndarray:
        """The robots in the run from its start to its end (a robot that rejoined missed configurations): every
        metric is computed over them."""
        if not self.configs:
            return self.initial_estimate.ids
        ids = self.configs[-1].estimate.ids
        for c in self.configs[:-1]:
            ids = ids[np.isin(ids, c.estimate.ids)]
        return ids

    def _rows(self, ids: np.ndarray) -> np.ndarray:
        """Rows of the finished robots in arrays ordered like ``ids``."""
        return index_of(ids, self.finished_ids, "run result")

    def true_configurations(self) -> np.ndarray:
        """(k + 1, n, 2): the true start, then the truth after each completed configuration (finished robots)."""
        assert self.initial_truth is not None, "simulated runs only"
        start = self.initial_truth[self._rows(self.initial_estimate.ids), :2]
        return np.stack([start, *[c.truth[self._rows(c.estimate.ids), :2] for c in self.configs]])  # type: ignore[index]  # simulated

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
        """n_a of the strategy's plan of each configuration (before any split for bodies: the steps show that)."""
        return np.array([(c.plan if c.regrouped is None else c.regrouped.planned).n_anchors for c in self.configs])

    def steps_per_config(self) -> np.ndarray:
        return np.array([c.n_steps for c in self.configs])

    def steps_added(self) -> int:
        """Steps the body constraint added to the strategies' plans, sub-steps and approach legs (Eq. 6-7 count the
        steps taken)."""
        return int(sum(c.n_steps - c.planned_steps for c in self.configs))

    def staging_stops(self) -> int:
        """Approach legs driven to a staging point over the run (``coordinator.legs``)."""
        return sum(c.staging_stops for c in self.configs)

    def holds(self) -> int:
        """Approach legs a robot waited in for a neighbour over the run (``coordinator.legs``)."""
        return sum(c.holds for c in self.configs)

    def corrections(self) -> int:
        """Correction legs driven over the run (``ConfigRecord.corrections``)."""
        return sum(c.corrections for c in self.configs)

    def stopped_short(self) -> list[list[int]]:
        """Per completed configuration, the robots its approach legs stopped short of their desired position on purpose
        (``coordinator.legs``: at risk there even with no motion noise, or the way blocked by a robot standing for the
        rest of the change), ids in order."""
        out: list[list[int]] = []
        for rec in self.configs:
            final: dict[int, np.ndarray] = {}
            for leg in rec.legs:  # a robot's last leg holds where it was sent in the end
                final.update((int(r), t) for r, t in zip(leg.ids, leg.targets, strict=True))
            ids = np.array(sorted(final), np.int64)
            if not len(ids):
                out.append([])
                continue
            desired = self.trajectory.configurations[rec.config][index_of(self.trajectory.ids, ids, "trajectory")]
            sent = np.array([final[int(r)] for r in ids])
            out.append(ids[np.hypot(*(sent - desired[:, :2]).T) > 0.0].tolist())
        return out

    def contacts(self, radius: float) -> list[ContactEvent]:
        """Contacts of bodies of ``radius`` (m) in the true motion of every step (``runtime.models.bodies.step_contacts``):
        each pair of robots whose bodies overlapped at some time of a step (a mover's, or two still robots standing
        too close), once per step. [] without ground truth."""
        if not self.has_truth or self.initial_truth is None or radius <= 0:
            return []
        before, before_ids, out = self.initial_truth, self.trajectory.ids, list[ContactEvent]()
        for number, rec in enumerate(self.steps, start=1):
            if rec.truth is None:
                return out
            out += contact_events(number, rec, before, before_ids, self.trajectory.ids, radius)
            before, before_ids = rec.truth, self.trajectory.ids if rec.truth_ids is None else rec.truth_ids
        return out


def contact_events(number: int, rec: StepRecord, before: np.ndarray, before_ids: np.ndarray, ids: np.ndarray,
                   radius: float) -> list[ContactEvent]:
    """The contacts of global step ``number`` (record ``rec``) from the true poses ``before`` it (rows: ``before_ids``)
    among the robots in both; ``ids``: the trajectory's robots (``rec.truth``'s rows unless it names them)."""
    assert rec.truth is not None  # a step with ground truth
    after_ids = ids if rec.truth_ids is None else rec.truth_ids
    common = np.intersect1d(before_ids, after_ids)
    start, end = before[index_of(before_ids, common, "truth")], rec.truth[index_of(after_ids, common, "truth")]
    moving = np.isin(common, rec.estimate.ids[rec.moving])
    return [ContactEvent(number, rec.config, int(common[c.a]), int(common[c.b]), c.distance, c.point)
            for c in step_contacts(start, end, moving, radius)]
