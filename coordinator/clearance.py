"""The body constraint applied to any strategy's plan (constraint g of Eq. 4, ``docs/bodies.md``).

``clear_plan`` checks every step of a plan under the nominal motion the robots execute and
splits the steps whose movers would come too close to each other or to a still robot into
sub-steps (``runtime.models.bodies.BodyCheck.regroup``). The executor applies it to every plan
before its first command, so every method runs collision-free; the replay check applies it
too, so a recorded plan is reproduced exactly. Point robots (radius 0): the plan unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from coordinator.plan import Plan
from runtime.models.bodies import CLEARANCE_SIGMAS, BodyCheck
from runtime.models.config import ModelConfig
from runtime.models.state import SwarmEstimate


@dataclass(frozen=True)
class Regrouping:
    """The strategy's plan (``planned``) had steps whose nominal motion brings bodies too close: it ran
    regrouped into sub-steps; ``unclear``: robot ids whose sub-steps no order cleared even with the bare 2R."""

    planned: Plan
    unclear: tuple[int, ...] = ()
    sigmas: float = CLEARANCE_SIGMAS  # the margin kept, in standard deviations (lower when no order kept the full one)

    @property
    def planned_steps(self) -> int:
        return self.planned.n_steps

    def describe(self, steps: int) -> str:
        text = (f"steps split for bodies: {self.planned_steps} -> {steps}" if steps != self.planned_steps
                else f"steps regrouped for bodies (still {steps})")
        if self.sigmas < CLEARANCE_SIGMAS:
            text += f" (margin lowered to {self.sigmas:g} sigma)"
        if self.unclear:
            text += f"; no collision-free order for robots {list(self.unclear)} (moved one at a time)"
        return text


def clear_plan(cfg: ModelConfig, plan: Plan, estimate: SwarmEstimate, desired: np.ndarray) -> tuple[Plan, Regrouping | None]:
    """``plan`` for moving ``estimate`` to ``desired`` (n, 2) with every step clear, and how it was split (None: unchanged)."""
    if cfg.robot_radius_m <= 0:
        return plan, None
    out = BodyCheck.of_estimate(cfg, estimate, desired).regroup(plan.groups)
    if len(out.groups) == plan.n_steps and all(np.array_equal(a, b) for a, b in zip(out.groups, plan.groups, strict=True)):
        return plan, None
    split = Plan(np.concatenate(out.groups), tuple(len(g) for g in out.groups))
    return split, Regrouping(plan, tuple(int(r) for r in estimate.ids[out.unclear]), out.sigmas)
