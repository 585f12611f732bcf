"""Inchworm plans (Section 4.1): which robots move at each step towards the next configuration.

A plan is an ordered partition of the robots into mobile groups; at step k the robots
of group k move and everyone else is an anchor. The paper's plans have n_s equal
groups of n_m = n_r - n_a robots, which requires n_s = n_r / (n_r - n_a) to be an
integer (Eq. 7). A plan is encoded as a permutation of robot indices cut into
consecutive groups, which is what the genetic search (Eq. 9) manipulates.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from typing import TypeAlias

import numpy as np

from runtime.errors import SwarmInputError

PlanKey: TypeAlias = tuple[tuple[int, ...], ...]  # ``Plan.key()``: each group's robots, sorted


def feasible_anchor_counts(n_robots: int) -> list[int]:
    """Anchor counts n_a with an integer number of steps n_s = n_r / (n_r - n_a) (Eq. 7).

    n_r = 10 gives [0, 5, 8, 9].
    """
    return [n_a for n_a in range(n_robots) if n_robots % (n_robots - n_a) == 0]


def n_steps(n_robots: int, n_anchors: int) -> int:
    """n_s (Eq. 7)."""
    if n_anchors not in feasible_anchor_counts(n_robots):
        raise SwarmInputError(f"{n_anchors} anchors is not feasible for {n_robots} robots (Eq. 7)")
    return n_robots // (n_robots - n_anchors)


def speed_performance(n_robots: int, n_anchors: int) -> float:
    """P_v = v(n_a) / v_max = 1 / n_s (Eq. 1, 6, 7)."""
    return 1.0 / n_steps(n_robots, n_anchors)


def n_partitions(sizes: tuple[int, ...]) -> int:
    """Ordered partitions of sum(sizes) robots into consecutive groups of these sizes:
    (sum sizes)! / prod(size!)."""
    return math.factorial(sum(sizes)) // math.prod(math.factorial(s) for s in sizes)


def n_solutions(n_robots: int, n_anchors: int) -> int:
    """Number of ordered partitions the inner loop searches (Eq. 10): n_s groups of n_m = n_r - n_a robots."""
    return n_partitions((n_robots - n_anchors,) * n_steps(n_robots, n_anchors))


@dataclass(frozen=True)
class Plan:
    """``order`` (a permutation of 0..n-1) cut into consecutive mobile groups of sizes ``sizes``."""

    order: np.ndarray
    sizes: tuple[int, ...]

    def __post_init__(self) -> None:
        order = np.asarray(self.order, dtype=np.int64)
        n = len(order)
        if not np.array_equal(np.sort(order), np.arange(n)):
            raise SwarmInputError(f"a plan's order must be a permutation of 0..{n - 1}, got {order.tolist()}")
        if sum(self.sizes) != n or any(s < 1 for s in self.sizes):
            raise SwarmInputError(f"group sizes {self.sizes} do not partition {n} robots")
        object.__setattr__(self, "order", order)
        object.__setattr__(self, "sizes", tuple(int(s) for s in self.sizes))

    @classmethod
    def equal(cls, order: np.ndarray, n_anchors: int) -> Plan:
        """The paper's plan: n_s groups of n_m = n - n_a robots (Eq. 7)."""
        n = len(order)
        return cls(order, (n - n_anchors,) * n_steps(n, n_anchors))

    @property
    def n_robots(self) -> int:
        return len(self.order)

    @property
    def n_steps(self) -> int:
        return len(self.sizes)

    @property
    def n_anchors(self) -> int:
        """Anchors of the largest step (= n_a for the paper's equal groups)."""
        return self.n_robots - min(self.sizes)

    @property
    def groups(self) -> list[np.ndarray]:
        """Mobile robot indices of each step."""
        ends = list(itertools.accumulate(self.sizes))
        return [self.order[end - size : end] for size, end in zip(self.sizes, ends, strict=True)]

    def moving(self, step: int) -> np.ndarray:
        """Mask (n,) of the robots that move at ``step``."""
        mask = np.zeros(self.n_robots, bool)
        mask[self.groups[step]] = True
        return mask

    def key(self) -> PlanKey:
        """Canonical form: the order of robots inside a group does not matter."""
        return tuple(tuple(sorted(g.tolist())) for g in self.groups)


def enumerate_plans(n: int, n_a: int) -> list[Plan]:
    """Every ordered partition of ``n`` robots into equal mobile groups of n - n_a (Eq. 10)."""
    size, plans = n - n_a, []

    def extend(prefix: list[int], rest: list[int]) -> None:
        if not rest:
            plans.append(Plan.equal(np.array(prefix), n_a))
            return
        for group in itertools.combinations(rest, size):
            extend(prefix + list(group), [r for r in rest if r not in group])

    extend([], list(range(n)))
    return plans
