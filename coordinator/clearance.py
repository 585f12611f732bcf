"""The body constraint applied to any strategy's plan (constraint g of Eq. 4, ``docs/bodies.md``).

``clear_plan`` checks every step of a plan against the chance constraint (the probability that a pair of
robots touches during a step at most ``CONTACT_BOUND``, ``runtime.models.bodies``) and splits the steps that
exceed it into sub-steps (``runtime.models.bodies.BodyCheck.regroup``). The executor applies it to every plan
before its first command, so every method runs under the constraint; the replay check applies it too, so a
recorded plan is reproduced exactly (the computation is deterministic). Point robots (radius 0): the plan unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from coordinator.plan import Plan
from runtime.models.bodies import CONTACT_BOUND, BodyCheck
from runtime.models.config import ModelConfig
from runtime.models.state import SwarmEstimate


@dataclass(frozen=True)
class Regrouping:
    """The strategy's plan (``planned``) had steps over the contact bound: it ran regrouped into sub-steps;
    ``bound``: the highest contact probability bound per pair and step kept (above ``CONTACT_BOUND`` when no order
    kept that); ``unclear``: robot ids no order kept within the highest bound (moved one at a time)."""

    planned: Plan
    unclear: tuple[int, ...] = ()
    bound: float = CONTACT_BOUND

    @property
    def planned_steps(self) -> int:
        return self.planned.n_steps

    def describe(self, steps: int) -> str:
        text = (f"steps split for bodies: {self.planned_steps} -> {steps}" if steps != self.planned_steps
                else f"steps regrouped for bodies (still {steps})")
        if self.bound > CONTACT_BOUND:
            text += f" (contact bound raised to {self.bound:g} per pair and step for some robots)"
        if self.unclear:
            text += f"; no order keeps robots {list(self.unclear)} within it (moved one at a time)"
        return text

    def to_json(self, steps: int) -> dict[str, Any]:
        """The additive ``--json`` record of the split: planned and taken steps, the bound kept, the unclear robots."""
        return {"planned_steps": self.planned_steps, "steps": steps, "contact_bound": self.bound, "unclear": list(self.unclear)}


def clear_plan(cfg: ModelConfig, plan: Plan, estimate: SwarmEstimate, desired: np.ndarray) -> tuple[Plan, Regrouping | None]:
    """``plan`` for moving ``estimate`` to ``desired`` (n, 2) with every step within the contact bound, and how it
    was split (None: unchanged)."""
    if cfg.robot_radius_m <= 0:
        return plan, None
    out = BodyCheck.of_estimate(cfg, estimate, desired).regroup(plan.groups)
    if len(out.groups) == plan.n_steps and all(np.array_equal(a, b) for a, b in zip(out.groups, plan.groups, strict=True)):
        return plan, None
    split = Plan(np.concatenate(out.groups), tuple(len(g) for g in out.groups))
    return split, Regrouping(plan, tuple(int(r) for r in estimate.ids[out.unclear]), out.bound)
