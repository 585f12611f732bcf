"""Robot bodies: discs of radius R, the clearance a planned step keeps, and the contacts of true motion.

Model (``docs/bodies.md``): a robot is a disc of radius R (m) centred on its position.
A step's movers turn in place (the centre does not move), then drive straight; they
start driving together and arrive together, each at a speed proportional to its
distance, so at normalised time s in [0, 1] robot i is at p_i + s (q_i - p_i); anchors
stay still. Two robots' relative position is then linear in s and their closest approach
over the step is the distance from the origin to a segment (closed form, vectorised over
all pairs). R = 0 is the paper's point robots: no clearance is checked.

Planned steps (``BodyCheck``, constraint g of Eq. 4) keep a chance constraint: the probability that a pair
with a mover touches during a step (at any time of it, continuously along the turn-then-drive motion) is at
most ``CONTACT_BOUND`` (1e-3) per pair and step. The probability is bounded from above
(``runtime.models.contact_risk``) from the predicted distribution of both robots over the motion: the estimate's
covariance at the start (and the joint covariance's cross terms when known) plus the exact growth of
turn-then-drive (``runtime.models.motion.motion_moments``); robots moved by earlier steps of the plan stand at
their predicted arrival with its covariance. Where the configurations themselves put a pair at risk p (both
standing at the start, or both arrived at the end: no order changes that), the pair may reach
``FLOOR_FACTOR`` x p. Where no order keeps the bound, the bound of the robots it leaves unclear is raised
through ``BOUND_LEVELS``, and robots no order keeps within the highest move one at a time.
"""

from __future__ import annotations

import copy
import functools
from dataclasses import dataclass
from typing import TYPE_CHECKING, cast

import numpy as np

from runtime.errors import SwarmInputError
from runtime.models.config import ModelConfig
from runtime.models.contact_risk import MotionMoments, instant_bound, step_bound
from runtime.models.state import SwarmEstimate
from runtime.models.substeps import schedule

if TYPE_CHECKING:
    from scipy.spatial import cKDTree


CONTACT_BOUND = 1e-3  # the chance constraint: P(contact) of a pair during a step at most this
BOUND_LEVELS = (1e-3, 1e-2, 1e-1)  # bounds tried in turn for the robots no order keeps within the lower one
FLOOR_FACTOR = 2.0  # a pair the configurations themselves put at risk p (standing at the start or the end) may reach 2 p
TOLERANCE = 1e-9  # relative: bounds within this of the allowed one are not conflicts (rounding)


def closest_time(offset: np.ndarray, velocity: np.ndarray) -> np.ndarray:
    """The s in [0, 1] minimising |offset + s velocity| for (..., 2) arrays (0 when ``velocity`` is 0)."""
    vv = np.einsum("...k,...k->...", velocity, velocity)
    return cast(np.ndarray, np.clip(-np.einsum("...k,...k->...", offset, velocity) / np.where(vv > 0, vv, 1.0), 0.0, 1.0))


def closest_approach(offset: np.ndarray, velocity: np.ndarray) -> np.ndarray:
    """min over s in [0, 1] of |offset + s velocity| for (..., 2) arrays (m): the closest approach
    of two robots whose relative position moves linearly from ``offset`` to ``offset + velocity``."""
    rel = offset + closest_time(offset, velocity)[..., None] * velocity
    return cast(np.ndarray, np.hypot(rel[..., 0], rel[..., 1]))


INDEX_MIN = 128  # robots from which candidate pairs come from a k-d tree (fewer: every pair, as cheap)
_SLACK_M = 1e-9  # candidate bounds are widened by this (rounding); conflicts are still decided exactly


def all_pairs(rows: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Every (i, j), i of ``rows``, j != i of ``n`` robots, in (position of i in ``rows``, j) order."""
    i = np.repeat(np.asarray(rows, np.int64), n)
    j = np.tile(np.arange(n), len(rows))
    keep = i != j
    return i[keep], j[keep]


def near_pairs(rows: np.ndarray, mid: np.ndarray, reach: np.ndarray, points: np.ndarray, spread: np.ndarray,
               tree: cKDTree | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Candidate pairs (i, j), i of ``rows``, j != i, in (position of i in ``rows``, j) order: every pair with
    |``mid``_i - ``points``_j| < ``reach``_i + ``spread``_j (+ rounding slack), found with a k-d tree of ``points``
    (``tree``, or built here). A pair of robots whose swept discs come within d of each other is kept when
    ``mid``/``reach`` bound robot i's disc over the step (its path's midpoint; half its length plus its pad) and
    every position robot j takes and its pad lie within ``spread``_j of ``points``_j, with the pads adding to d."""
    from scipy.spatial import cKDTree  # noqa: PLC0415 - scipy only when checked (cheap parsers)

    rows = np.asarray(rows, np.int64)
    if tree is None:
        tree = cKDTree(points)
    if not len(rows):
        return rows, rows
    reach_rows = reach[rows]
    found = cKDTree(mid[rows]).sparse_distance_matrix(tree, float(reach_rows.max() + spread.max()) + _SLACK_M, output_type="ndarray")
    k, j = found["i"].astype(np.int64), found["j"].astype(np.int64)
    keep = (rows[k] != j) & (found["v"] < reach_rows[k] + spread[j] + _SLACK_M)
    k, j = k[keep], j[keep]
    order = np.lexsort((j, k))
    return rows[k[order]], j[order]


@dataclass(frozen=True)
class Contact:
    """Two robots (indices a < b into the step's arrays) whose bodies touched: centres ``distance`` m apart at
    the closest, ``point`` (x, y) m midway between them then."""

    a: int
    b: int
    distance: float
    point: tuple[float, float]


def step_contacts(before: np.ndarray, after: np.ndarray, moving: np.ndarray, radius: float) -> list[Contact]:
    """Pairs (a < b) whose centres came closer than 2 ``radius`` during the step from ``before`` to ``after``
    (n, >= 2) under the timing model: pairs with a mover over the whole motion, and pairs of still robots that
    stand closer than that (left touching by an earlier step, or pushed there); still robots' rows are not read
    from ``after``."""
    if radius <= 0:
        return []
    start = np.asarray(before, float)[:, :2]
    end = np.where(np.asarray(moving)[:, None], np.asarray(after, float)[:, :2], start)
    moving = np.asarray(moving, bool)
    movers, still = np.flatnonzero(moving), np.flatnonzero(~moving)
    touching = overlapping_pairs(start[still], radius)
    out = [Contact(int(still[p]), int(still[q]), float(np.hypot(*(start[still[p]] - start[still[q]]))),
                   (float((start[still[p], 0] + start[still[q], 0]) / 2.0), float((start[still[p], 1] + start[still[q], 1]) / 2.0)))
           for p, q in touching.tolist()]
    if not len(movers):
        return sorted(out, key=lambda c: (c.a, c.b))
    disp = end - start
    if len(start) < INDEX_MIN:
        i, j = all_pairs(movers, len(start))
    else:  # i's centre stays within half its path of its midpoint, j's within its path of its start
        length = np.hypot(*disp.T)
        i, j = near_pairs(movers, start + disp / 2.0, length / 2.0 + radius, start, length + radius)
    once = ~moving[j] | (j > i)  # each mover pair once
    i, j = i[once], j[once]
    d = closest_approach(start[i] - start[j], disp[i] - disp[j])
    hit = d < 2.0 * radius
    i, j, d = i[hit], j[hit], d[hit]
    s = closest_time(start[i] - start[j], disp[i] - disp[j])[:, None]
    mid = (start[i] + start[j] + s * (disp[i] + disp[j])) / 2.0
    out += [Contact(int(min(a, b)), int(max(a, b)), float(x), (float(m[0]), float(m[1])))
            for a, b, x, m in zip(i, j, d, mid, strict=True)]
    return sorted(out, key=lambda c: (c.a, c.b))


@functools.lru_cache(maxsize=16)
def reach_sigmas(bound: float) -> float:
    """z with 2 Phi(-z) = ``bound``."""
    from scipy.special import ndtri  # noqa: PLC0415 - scipy only when checked (cheap parsers)

    return float(-ndtri(bound / 2.0))


@dataclass(frozen=True)
class PairRisks:
    """Contact probability bounds of candidate pairs (i, j) (``BodyCheck.pair_risks``), i driving its move and j
    standing where it starts (``start``), standing where it arrives (``end``) or moving with i (``moving``, 0 where j
    is not among the robots regrouped; judged as ``step_conflicts`` judges a pair of movers, the lower index driving,
    so (i, j) and (j, i) hold the same bound); ``floor``: the bound the configurations allow the pair
    (``BodyCheck._floor``, 0 where no bound of ``start`` or ``end`` exceeded the strictest one in use), ``floor_moving``
    the same for ``moving`` (the lower index first). Each (m,). The one source of pair verdicts: the regrouping's
    schedule (``over``) and the anchor search's tables (``tables``) read them."""

    i: np.ndarray
    j: np.ndarray
    start: np.ndarray
    end: np.ndarray
    moving: np.ndarray
    floor: np.ndarray
    floor_moving: np.ndarray

    def over(self, levels: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(start, end, moving) (m,): the pairs at too much risk when robot r's bound is ``levels`` [r] (a pair keeps
        the higher of its two, or its floor where that is higher still: ``BodyCheck._risk``)."""
        allowed = np.maximum(levels[self.i], levels[self.j])

        def bad(p: np.ndarray, floor: np.ndarray) -> np.ndarray:
            return np.asarray(p > np.where(p > allowed, np.maximum(allowed, floor), allowed) * (1.0 + TOLERANCE))

        return bad(self.start, self.floor), bad(self.end, self.floor), bad(self.moving, self.floor_moving)

    def tables(self, levels: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``over`` as three (n, n) bool tables of ``n`` robots (row: the driving robot): (together, at_start,
        at_arrival); pairs that are not candidates are clear."""
        start, end, moving = self.over(levels)
        out = []
        for bad in (moving, start, end):
            table = np.zeros((n, n), bool)
            table[self.i[bad], self.j[bad]] = True
            out.append(table)
        return out[0], out[1], out[2]


@dataclass(frozen=True)
class Conflict:
    """A planned pair (robot indices) at too much risk: contact ``probability`` (the bound of ``contact_risk``) above
    the ``allowed`` one; ``closest``: the closest approach of their mean positions in the step (m)."""

    a: int
    b: int
    closest: float
    probability: float
    allowed: float


class BodyCheck:
    """The chance constraint on the steps of plans for one configuration change (``current`` -> ``desired``, (n, 2) m).

    ``cov`` (n, 3, 3): each robot's pose covariance at the start (default: ``position_var`` m^2 on both axes and
    ``heading_var`` rad^2, uncorrelated); ``joint`` (3n, 3n): the swarm's joint covariance for the cross terms (None:
    robots uncorrelated). ``cfg.robot_radius_m`` = 0 checks nothing.
    """

    def __init__(self, cfg: ModelConfig, current: np.ndarray, desired: np.ndarray,
                 position_var: np.ndarray | float = 0.0, heading_var: np.ndarray | float = 0.0,
                 cov: np.ndarray | None = None, joint: np.ndarray | None = None) -> None:
        self.radius = float(cfg.robot_radius_m)
        self.current = np.asarray(current, float)[:, :2]
        self.desired = np.asarray(desired, float)[:, :2]
        n = len(self.current)
        self.bound = CONTACT_BOUND  # the bound per pair and step (the highest, when ``levels`` are set)
        self.levels: np.ndarray | None = None  # per robot, when bounds differ (``with_levels``)
        if cov is None:
            cov = np.zeros((n, 3, 3))
            cov[:, 0, 0] = cov[:, 1, 1] = np.broadcast_to(np.asarray(position_var, float), (n,))
            cov[:, 2, 2] = np.broadcast_to(np.asarray(heading_var, float), (n,))
        self.moments = MotionMoments(cfg, self.current, self.desired, np.asarray(cov, float), joint)
        self.arrival = self.current + self.moments.step  # each robot's mean position after its move
        self.sd = self.moments.spread()
        self.has_path = np.any(self.desired != self.current, axis=1)
        self._conflicts: dict[bytes, tuple[Conflict, ...]] = {}  # step_conflicts by (before, moving): plans share steps
        self._trees: dict[bytes, tuple[cKDTree, np.ndarray]] = {}  # ``_index`` by the robots moved

    @classmethod
    def of_estimate(cls, cfg: ModelConfig, estimate: SwarmEstimate, desired: np.ndarray) -> BodyCheck:
        """The check for moving ``estimate`` to ``desired``, with its covariances (the joint one when known). The
        anchor search, the study of its optimum and ``clear_plan`` all build their constraint here."""
        return cls(cfg, estimate.positions, desired, cov=estimate.cov, joint=estimate.joint)

    @property
    def active(self) -> bool:
        return self.radius > 0

    def _moved(self, before: np.ndarray) -> np.ndarray:
        """(n,) the robots that stand at their desired positions in ``before`` (n, 2) having moved there."""
        return cast(np.ndarray, self.has_path & np.all(np.asarray(before)[:, :2] == self.desired, axis=1))

    def _lowest(self) -> float:
        """The strictest bound in use."""
        return self.bound if self.levels is None else float(self.levels.min())

    def _reach_sigmas(self) -> float:
        """z with 2 Phi(-z) = the strictest bound in use: a pair whose mean positions stay more than
        2R + z (sd_i + sd_j) apart has a step bound below it (the whole step's interval, w along the closest approach)."""
        return reach_sigmas(self._lowest())

    def _candidates(self, rows: np.ndarray, moved: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pairs (i, j), i of ``rows`` driving from its current position, j != i standing where ``moved`` puts it or
        on its way from there to its arrival, that may be at risk, in (position of i in ``rows``, j) order. Below
        ``INDEX_MIN`` robots every pair; from there the candidates of a k-d tree (``near_pairs``): a pair at risk
        needs |mid_i - x_j| < half_i + L_j + (R + z sd_i) + (R + z sd_j) (``_reach_sigmas``)."""
        rows = np.asarray(rows, np.int64)
        n = len(self.current)
        if n < INDEX_MIN:
            return all_pairs(rows, n)
        tree, spread = self._index(moved)
        z = self._reach_sigmas()
        step = self.moments.step
        mid = np.zeros_like(self.current)
        mid[rows] = self.current[rows] + step[rows] / 2.0
        reach = np.zeros(n)
        reach[rows] = np.hypot(*step[rows].T) / 2.0 + self.radius + z * self.sd[rows]
        return near_pairs(rows, mid, reach, tree.data, spread, tree)

    def _index(self, moved: np.ndarray) -> tuple[cKDTree, np.ndarray]:
        """A k-d tree of the robots' mean positions (``moved``: at their arrival, else at their current position)
        and each robot's spread there: its remaining path to its arrival plus its largest pad R + z sd, in m."""
        key = moved.tobytes() + np.float64(self._reach_sigmas()).tobytes()
        found = self._trees.get(key)
        if found is None:
            from scipy.spatial import cKDTree  # noqa: PLC0415 - scipy only for large swarms

            base = np.where(moved[:, None], self.arrival, self.current)
            spread = np.hypot(*(self.arrival - base).T) + self.radius + self._reach_sigmas() * self.sd
            if len(self._trees) >= 64:  # plans of a large swarm share few step configurations
                self._trees.clear()
            found = self._trees[key] = (cKDTree(base), spread)
        return found

    def _bounds(self, i: np.ndarray, j: np.ndarray, fixed_j: np.ndarray, moves_j: np.ndarray,
                enough: np.ndarray | float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(contact probability bound, mu_0, v) of pairs (i, j): i drives its move, j is at t = ``fixed_j`` + s
        ``moves_j`` (0/1 arrays; ``contact_risk``); a bound at most ``enough`` may be the coarse one."""
        ones, zeros = np.ones(len(i)), np.zeros(len(i))
        mu0, v, s0, s1, s2 = self.moments.pairs(i, j, zeros, ones, fixed_j, moves_j)
        p = step_bound(mu0, v, s0, s1, s2, 2.0 * self.radius, self.has_path[i] | ((moves_j > 0) & self.has_path[j]), enough)
        return p, mu0, v

    def _floor(self, i: np.ndarray, j: np.ndarray) -> np.ndarray:
        """The bound the configurations allow pairs (i, j): ``FLOOR_FACTOR`` x the larger of their risk standing at the
        start (both before their moves) and at the end (both after), at most 1."""
        zeros = np.zeros(len(i))
        floor = np.zeros(len(i))
        for t in (0.0, 1.0):
            at = np.full(len(i), t)
            m0, _, c0, _, _ = self.moments.pairs(i, j, at, zeros, at, zeros)
            floor = np.maximum(floor, instant_bound(m0, c0, 2.0 * self.radius))
        return np.asarray(np.minimum(FLOOR_FACTOR * floor, 1.0))

    def _risk(self, i: np.ndarray, j: np.ndarray, fixed_j: np.ndarray,
              moves_j: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(at risk, contact probability bound, allowed bound, closest mean approach m) of pairs (i, j): i drives its
        move, j is at t = ``fixed_j`` + s ``moves_j`` (0/1 arrays; ``contact_risk``).

        A pair's allowed bound is the bound of the check (or the higher of its robots' ``levels``), or more where the
        configurations themselves put it at risk (``_floor``): no plan can do better than the configurations."""
        allowed = np.full(len(i), self.bound) if self.levels is None else np.maximum(self.levels[i], self.levels[j])
        p, mu0, v = self._bounds(i, j, fixed_j, moves_j, allowed)
        over = np.flatnonzero(p > allowed)
        if len(over):  # the configurations' own risk, only where it could matter
            allowed[over] = np.maximum(allowed[over], self._floor(i[over], j[over]))
        return p > allowed * (1.0 + TOLERANCE), p, allowed, closest_approach(mu0, v)

    def pair_risks(self, robots: np.ndarray) -> PairRisks:
        """The bounds of every candidate pair (i, j), i of ``robots`` driving its move, with j standing where it
        starts, standing where it arrives and (j of ``robots``) moving with i: all a regrouping of ``robots``
        needs, at any robots' bounds (``PairRisks.over``), and, of every robot, the anchor search's tables
        (``pair_tables``)."""
        robots = np.asarray(robots, np.int64)
        n = len(self.current)
        i, j = self._candidates(robots, np.zeros(n, bool))
        enough = self._lowest()
        zeros = np.zeros(len(i))
        start = self._bounds(i, j, zeros, zeros, enough)[0]
        end, moving = start.copy(), np.zeros(len(i))
        ahead = np.flatnonzero(self.has_path[j])  # only a robot with a path stands elsewhere when it has arrived
        end[ahead] = self._bounds(i[ahead], j[ahead], np.ones(len(ahead)), zeros[ahead], enough)[0]
        mover = np.zeros(n, bool)
        mover[robots] = True
        both = np.flatnonzero(mover[j])
        low, high = np.minimum(i, j), np.maximum(i, j)  # a pair of movers as ``step_conflicts`` judges it
        moving[both] = self._bounds(low[both], high[both], zeros[both], np.ones(len(both)), enough)[0]
        floor, floor_moving = np.zeros(len(i)), np.zeros(len(i))
        over = np.flatnonzero((start > enough) | (end > enough))
        floor[over] = self._floor(i[over], j[over])
        over = np.flatnonzero(moving > enough)
        floor_moving[over] = self._floor(low[over], high[over])
        return PairRisks(i, j, start, end, moving, floor, floor_moving)

    def robot_levels(self) -> np.ndarray:
        """(n,) each robot's bound (``levels``, else the check's bound for all)."""
        return np.full(len(self.current), self.bound) if self.levels is None else self.levels

    def pair_tables(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(together, at_start, at_arrival) (n, n) bool, row i the driving robot: whether robot i's move conflicts
        with robot j moving in the same step, standing where j starts, standing where j arrives (``PairRisks.tables``
        of every robot at the robots' bounds): the verdicts of ``step_conflicts`` pair by pair, every step of every
        plan read from them. All False when nothing is checked (radius 0)."""
        n = len(self.current)
        if not self.active:
            return np.zeros((n, n), bool), np.zeros((n, n), bool), np.zeros((n, n), bool)
        return self.pair_risks(np.arange(n)).tables(self.robot_levels(), n)

    def step_conflicts(self, before: np.ndarray, moving: np.ndarray) -> list[Conflict]:
        """The conflicts of one step: robots at ``before`` (n, 2; each at its current or its desired position),
        ``moving`` (n,) drive to their desired positions."""
        movers = np.flatnonzero(moving)
        if not self.active or not len(movers):
            return []
        key = np.asarray(before, float).tobytes() + np.asarray(moving, bool).tobytes()
        found = self._conflicts.get(key)
        if found is None:
            moving = np.asarray(moving, bool)
            moved = self._moved(before) & ~moving
            i, j = self._candidates(movers, moved)
            once = ~moving[j] | (j > i)  # each mover pair once
            i, j = i[once], j[once]
            bad, p, allowed, closest = self._risk(i, j, moved[j].astype(float), moving[j].astype(float))
            found = self._conflicts[key] = tuple(Conflict(int(min(a, b)), int(max(a, b)), float(c), float(q), float(r))
                                                 for a, b, c, q, r in zip(i[bad], j[bad], closest[bad], p[bad], allowed[bad], strict=True))
        return list(found)

    def is_clear(self, groups: list[np.ndarray]) -> bool:
        """Whether no step of ``groups`` has a conflict (constraint g of Eq. 4)."""
        if not self.active:
            return True
        before = self.current.copy()
        for group in groups:
            moving = np.zeros(len(before), bool)
            moving[group] = True
            if self.step_conflicts(before, moving):
                return False
            before[group] = self.desired[group]
        return True

    def with_bound(self, bound: float) -> BodyCheck:
        """The same check with a contact probability bound of ``bound`` per pair and step."""
        out = copy.copy(self)
        out.bound, out.levels = float(bound), None
        out._conflicts, out._trees = {}, {}
        return out

    def with_levels(self, levels: np.ndarray) -> BodyCheck:
        """The same check with a bound of ``levels`` (n,) per robot; a pair keeps the higher of its two."""
        if np.all(levels == levels[0]):
            return self.with_bound(float(levels[0]))
        out = self.with_bound(float(np.max(levels)))
        out.levels = np.asarray(levels, float).copy()
        return out

    def regroup(self, groups: list[np.ndarray]) -> Regrouped:
        """``groups`` split into sub-steps that keep the chance constraint (``docs/bodies.md``).

        The sub-steps are a schedule of the robots' single moves under the pairs' constraints
        (``runtime.models.substeps``); if it leaves robots that no order clears, the bound of those robots is
        raised to the next of ``BOUND_LEVELS``, the others keeping theirs, in turn. If even the highest fails,
        ``unclear`` names the robots whose sub-steps could not be cleared (they move one at a time where the order
        places them); ``bound`` is the highest bound used.
        """
        groups = [np.asarray(g, dtype=np.int64) for g in groups]
        if not self.active or self.is_clear(groups):
            return Regrouped(groups, [], self.bound)
        n = len(self.current)
        risks = self.pair_risks(np.concatenate(groups))
        levels = np.full(n, self.bound)
        while True:
            moves, unclear = self._schedule(groups, risks, levels, np.zeros(n, bool))
            higher = [r for r in unclear if levels[r] < max(BOUND_LEVELS)]
            if not unclear or not higher:
                return Regrouped(moves, unclear, float(levels.max()), levels if np.any(levels != levels[0]) else None)
            for r in higher:  # only the robots no order clears get the next higher bound
                levels[r] = min(k for k in BOUND_LEVELS if k > levels[r])

    def ordered_moves(self, robots: np.ndarray, done: np.ndarray, part: np.ndarray | None = None) -> tuple[list[np.ndarray], list[int]]:
        """Sub-steps that move ``robots`` each once, every sub-step clear, and []; the robots of ``done`` stand at
        their desired positions, the others at their current ones; ``part`` (n,): each robot's group (a sub-step keeps
        to one, None: all one group). When a sub-step cannot be cleared, its robots move one at a time there and are
        returned as the second value (``runtime.models.substeps``)."""
        robots = np.asarray(robots, np.int64)
        keys = np.zeros(len(robots), np.int64) if part is None else np.asarray(part)[robots]
        by_part = np.argsort(keys, kind="stable")
        groups = np.split(robots[by_part], np.flatnonzero(np.diff(keys[by_part])) + 1)
        return self._schedule(groups, self.pair_risks(robots), self.robot_levels(), np.asarray(done, bool))

    def _schedule(self, groups: list[np.ndarray], risks: PairRisks, levels: np.ndarray,
                  done: np.ndarray) -> tuple[list[np.ndarray], list[int]]:
        """``substeps.schedule`` of ``groups`` from the pairs of ``risks`` over the robots' bounds ``levels``; the
        robots of no group stand at their desired positions where ``done``, else at their current ones."""
        n = len(self.current)
        start, end, moving = risks.over(levels)
        i, j = risks.i, risks.j
        mine = np.zeros(n, bool)
        mine[np.concatenate(groups)] = True
        ours = mine[j]
        needs = (np.concatenate([i[start & ours], j[end & ours]]), np.concatenate([j[start & ours], i[end & ours]]))
        blocked = np.zeros(n, bool)
        blocked[i[~ours & np.where(done[j], end, start)]] = True
        return schedule(groups, n, needs, (i[moving & ours], j[moving & ours]), blocked)


@dataclass(frozen=True)
class Regrouped:
    """The groups of a plan that keep the chance constraint, with a contact bound of ``bound`` per pair and step at
    most; ``unclear``: robots no order kept within the highest of ``BOUND_LEVELS`` (moved one at a time);
    ``levels`` (n,): each robot's bound where they differ (``BodyCheck.with_levels``), else None."""

    groups: list[np.ndarray]
    unclear: list[int]
    bound: float
    levels: np.ndarray | None = None


def overlapping_pairs(xy: np.ndarray, radius: float) -> np.ndarray:
    """(m, 2) index pairs i < j of positions ``xy`` (n, 2) closer than 2 ``radius`` (m)."""
    if radius <= 0 or len(xy) < 2:
        return np.zeros((0, 2), np.int64)
    from scipy.spatial import cKDTree  # noqa: PLC0415 - scipy only when checked (cheap parsers)

    pairs = cKDTree(xy).query_pairs(2.0 * radius, output_type="ndarray")
    if not len(pairs):
        return np.zeros((0, 2), np.int64)
    d = np.linalg.norm(xy[pairs[:, 0]] - xy[pairs[:, 1]], axis=1)
    return cast(np.ndarray, pairs[d < 2.0 * radius])


def check_apart(xy: np.ndarray, ids: np.ndarray, radius: float, where: str) -> None:
    """Raise ``SwarmInputError`` naming ``where`` and the robots whose bodies of ``radius`` overlap in ``xy``."""
    pairs = overlapping_pairs(xy, radius)
    if len(pairs):
        i, j = pairs[0]
        more = f" (and {len(pairs) - 1} more pairs)" if len(pairs) > 1 else ""
        raise SwarmInputError(
            f"{where}: robots {int(ids[i])} and {int(ids[j])} overlap: centres {np.linalg.norm(xy[i] - xy[j]):.4f} m apart, "
            f"bodies of radius {radius:g} m need {2 * radius:g} m{more} (robot radius 0: point robots)"
        )


def impassable_pairs(start: np.ndarray, end: np.ndarray, radius: float) -> np.ndarray:
    """(m, 2) index pairs i < j that cannot both go from ``start`` to ``end`` (n, 2) without their bodies of
    ``radius`` touching, whatever the others do: i first (i's path passes j's start or j's path i's end),
    j first, and both together all bring the centres closer than 2 ``radius`` (e.g. a swap in a tight spot)."""
    n = len(start)
    if radius <= 0 or n < 2:
        return np.zeros((0, 2), np.int64)
    path = end - start
    if n < INDEX_MIN:
        i, j = np.triu_indices(n, 1)
    else:  # all three need the paths' discs within 2R: |mid_i - mid_j| < half_i + half_j + 2R
        half = np.hypot(*path.T) / 2.0 + radius
        i, j = near_pairs(np.arange(n), start + path / 2.0, half, start + path / 2.0, half)
        i, j = i[i < j], j[i < j]

    def near(offset: np.ndarray, velocity: np.ndarray) -> np.ndarray:
        return closest_approach(offset, velocity) < 2.0 * radius

    i_first = near(start[i] - start[j], path[i]) | near(start[j] - end[i], path[j])  # i passes j's start, j then i's end
    j_first = near(start[j] - start[i], path[j]) | near(start[i] - end[j], path[i])
    together = near(start[i] - start[j], path[i] - path[j])
    bad = i_first & j_first & together
    return np.column_stack([i[bad], j[bad]])
