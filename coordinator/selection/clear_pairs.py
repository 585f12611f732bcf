"""The body check of whole plans (constraint g of Eq. 4, ``docs/bodies.md``) from three tables of pair verdicts.

``BodyCheck.step_conflicts`` judges every pair of a step on its own (the chance constraint bounds the contact
probability of each pair and step): robot i driving from its start to its arrival against robot j that

* drives its own move in the same step (``together``),
* stands at its start, not moved yet (``at_start``), or
* stands at its arrival, moved in an earlier step (``at_arrival``).

A plan's conflicts are therefore those three verdicts looked up for each pair of robots by the steps the plan
gives them: both in step k, a conflict of step k if ``together``; i in step k before j, a conflict of step k if
``at_start[i, j]`` and one of j's step if ``at_arrival[j, i]``. The tables are ``BodyCheck.pair_tables``: the
bounds of every pair in the three situations, computed once (``BodyCheck.pair_risks``, the same pair bounds the
regrouping schedules from), judged as ``step_conflicts`` judges them; hundreds of plans are then judged by lookups.
"""

from __future__ import annotations

import numpy as np

from coordinator.plan import Plan
from runtime.models.bodies import BodyCheck


class PairTable:
    """The three (n, n) verdict tables of one ``BodyCheck`` (row: the driving robot) and the plans' conflicts from them."""

    def __init__(self, bodies: BodyCheck) -> None:
        self.current, self.desired = bodies.current, bodies.desired
        self.together, self.at_start, self.at_arrival = bodies.pair_tables()

    def clear(self, plans: list[Plan]) -> np.ndarray:
        """(plans,) whether no step of each plan has a conflict."""
        if not plans:
            return np.zeros(0, bool)
        step = np.stack([plan_steps(p) for p in plans])[:, :, None]  # (P, n, 1) step of each robot
        later = step.transpose(0, 2, 1)  # (P, 1, n)
        bad = ((step == later) & self.together) | ((step < later) & (self.at_start | self.at_arrival.T))
        clear: np.ndarray = ~bad.any(axis=(1, 2))
        return clear

    def conflicting(self, plan: Plan) -> np.ndarray:
        """The conflicting pairs (m, 2) of every step of ``plan`` as (driver, other), each pair once: the driver moves
        in the step of the conflict (a pair of movers: the lower index drives)."""
        step = plan_steps(plan)
        mine, other = step[:, None], step[None, :]
        bad = ((mine == other) & np.triu(self.together, 1)) | ((mine < other) & self.at_start) | ((mine > other) & self.at_arrival)
        return np.argwhere(bad)

    def step_counts(self, plan: Plan) -> list[int]:
        """Conflicting pairs of each step of ``plan``."""
        counts: list[int] = np.bincount(plan_steps(plan)[self.conflicting(plan)[:, 0]], minlength=plan.n_steps).tolist()
        return counts


def plan_steps(plan: Plan) -> np.ndarray:
    """(n,) the step in which each robot of ``plan`` moves."""
    step = np.empty(plan.n_robots, np.int64)
    step[plan.order] = np.repeat(np.arange(plan.n_steps), plan.sizes)
    return step
