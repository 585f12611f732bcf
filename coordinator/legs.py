"""Approach legs: a mover whose open-loop drive would end too close to a neighbour stops short first (docs/bodies.md).

Drive noise grows with the distance driven (``runtime.models.motion.motion_moments``), so a long open-loop drive ends
with a large position error, and where its target stands close to a neighbour's place the pair's contact risk at the
end of the change exceeds ``CONTACT_BOUND`` whatever the order of the moves (``BodyCheck``'s floor lets it through).
Such a mover drives in legs: first to a **staging point** on its straight way (a fraction of its remaining path,
``LEG_FRACTIONS``), the swarm re-localizes as after any step, and the next leg starts from the new estimate, shorter
and so more precise, until the rest of the way ends within the bound (or the robot drives its ``MAX_LEGS``-th leg: it
goes straight to the target, as without legs).

``leg_targets`` decides one leg of every robot still on its way from the estimate at the leg's start, the desired
configuration and which robots waited in the change's earlier legs (``next_leg``), nothing else, so the executor and
``swarm replay --check`` compute the same legs: the leg's end
configuration (each robot arrived at its leg's end with that drive's noise, the others where they stand) keeps every
pair's contact probability within ``CONTACT_BOUND``; the motion of the legs' steps is kept within it by the
regrouping, as for any step (``first_leg``, ``next_leg``). The end is one instant, so the criterion is the probability
of the pair's Gaussian relative position in the disc (``runtime.models.contact_risk.disc_probability``), not the
half-plane bound the steps need (``instant_bound``: 2.3-2.6x the probability in the median at the default noise,
10-27x at x5.58 for pairs at 1-3 %): a leg is driven only where the straight drive's end really is over the bound.

**Separated in time.** Two robots of a leg whose ways converge can be over the bound even both at their shortest
staging points: driving both there (as before) is where almost every contact at motion noise x5.58 came from. One of
them **waits** where it stands for the leg instead (``Leg.held``; the one with the longer way left, ties the higher
index, unless only the other order keeps the pair within the bound), the other approaches the standing, re-localized
robot over short legs, its ends kept within the bound also against the waiting robot's goal; then the waiting one
approaches. The choice is a function of the leg's start alone and consistent from leg to leg: the waiting robot's way
stays as long while the other's shrinks, so the same robot keeps waiting until the pair is clear, no alternation.
Waiting legs do not count against a robot's ``MAX_LEGS`` (its last leg, straight to its goal, is its ``MAX_LEGS``-th
driven one), a change ends after ``LEG_CAP`` legs at most (every robot still on its way drives straight in the last),
and every leg drives at least one robot (``leg_targets``).

A goal at risk even reached with no motion noise (the targets too close for the position uncertainty the robots have
now: no approach helps) is pulled back along the robot's way until every pair of goals keeps the bound (``safe_goals``):
the robot ends the change **stopped short** of its desired position instead of driving into contact, and the run says
so (``RunResult.stopped_short``). Against a robot that **stands for the rest of the change** (arrived, or not moving in
it) nobody waits: a mover over the bound against it even at its shortest staging point takes a shorter leg, the
farthest of its way in ``STOP_STEP`` steps whose end keeps the bound, and re-plans from there; where no such step is
left, or on its last leg, it ends the change there, stopped short (``_short_of_standing``: ways are straight, and one
that passes a standing robot closer than the bound allows is not driven). When every robot of a leg would wait, the
one whose leg's end is least at risk drives.

**A stricter bound at the leg ends.** A leg's end is where a pair that touches has been left by the motion of the
steps (a robot driven in, a neighbour standing), and a staging point is cheap: a robot stops shorter while a pair's
probability at the end is over ``END_BOUND`` = 1e-4 (a tenth of the steps' bound; a pair whose goals are at risk p
even reached with no motion may reach ``FLOOR_FACTOR`` x p, at most ``CONTACT_BOUND``), and of two robots still over it
at their shortest one waits; against a robot standing for the rest of the change a robot still over it at its shortest
staging point stages shorter, at the farthest ``STOP_STEP`` of its way whose end keeps it, where one does (else there,
within ``CONTACT_BOUND``), and it stops short of its goal against such a robot only over ``CONTACT_BOUND``.
**The way, too**: a drive whose straight way passes a robot standing for the rest of the change over the steps' bound
(``BodyCheck.step_conflicts``; no order helps it, and the regrouping would have moved it anyway) is blocked like one
whose end is over: it stops short before (``_passing_standing``); so is one past a robot that only corrects its place
in the same leg (a drive shorter than a body radius), judged where that robot stands and where it arrives. **The
change's last leg** (``LEG_CAP``): a robot that would wait ends the change where it stands, and the others stop short of
it and of every standing robot as on a last leg (it drove straight in before, past and into standing robots).

**Corrections.** After a leg, a robot that has arrived (or stands) but whose pair with a neighbour is over
``CONTACT_BOUND`` by the new estimate, both standing, and would be at most half as much at risk at its goal, drives back
towards its goal in the next leg (``corrections``): a pair the drive's error left touching is separated at once, instead
of standing so for the rest of the change (a contact at every step). A change whose legs are done ends only when no such
robot is left, or after ``LEG_CAP`` legs. For the same reason a robot over the bound against one that waits waits too only
where waiting helps: not where their pair is at least as much at risk standing where they are as with it at its leg's
end (``_waits_too``: two robots left touching waited side by side, leg after leg).

**A touch ends the leg.** After every step of a change, a pair the step left touching (``new_touches``) ends the leg
there: its remaining groups are not run (``LegRecord.groups_run``), their robots go on in the next leg, planned at once,
whose groups with a robot standing over ``CONTACT_BOUND`` go first (``next_leg``); a change without legs becomes a
first leg ending there (``coordinator.executor``). **A step at risk is not driven**: the leg's steps were judged at its
start with every robot at its planned end; a robot whose step in the leg is over the steps' bound against a robot an
earlier step of it moved, where the estimate now puts it (the drive's error left it in the way), stands in that step
and goes on in the next leg, planned from the estimate (``deferred_movers``, ``LegRecord.deferred``; the others of its
group drive, kept clear of it standing); where that is the whole group, the leg ends before it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from coordinator.clearance import Regrouping, clear_plan
from coordinator.plan import Plan
from runtime.models.bodies import CONTACT_BOUND, FLOOR_FACTOR, INDEX_MIN, BodyCheck, all_pairs, near_pairs, reach_sigmas
from runtime.models.config import ModelConfig
from runtime.models.contact_risk import MotionMoments, disc_probability, instant_bound
from runtime.models.state import SwarmEstimate, index_of

LEG_FRACTIONS = (0.75, 0.5, 0.25)  # staging points tried, as fractions of the remaining path, farthest first
MAX_LEGS = 6  # legs one robot drives in a change at most (the last drives straight to its target; waiting legs not counted)
LEG_CAP = 2 * MAX_LEGS  # legs of a change at most (in the last every robot still on its way drives to its goal, or stops short)
MIN_LEG_M = 1e-3  # a remaining path shorter than this (m) is driven in one leg
STOP_STEP = 1.0 / 16.0  # a goal at risk is pulled back along the robot's path by this fraction of it at a time
END_BOUND = 1e-4  # contact probability a pair may have at a leg's end (at most FLOOR_FACTOR x its goals' own, <= CONTACT_BOUND)


@dataclass(frozen=True)
class Leg:
    """One leg of a configuration change: ``targets`` (n, 2) m the robots drive to (their place for robots that do
    not move in it); ``staged`` (n,) the robots whose target is a staging point short of their goal; ``short`` (n,) the
    robots whose goal is short of their desired position (``safe_goals``: stopped short); ``held`` (n,) the robots that
    wait where they stand in this leg for a neighbour (their target is their place; they go on in the next leg).
    A robot blocked by one standing for the rest of the change (``_short_of_standing``) and ending the change short is
    in ``short`` too."""

    targets: np.ndarray
    staged: np.ndarray
    short: np.ndarray
    held: np.ndarray

    @property
    def any(self) -> bool:
        return bool(self.staged.any() or self.short.any() or self.held.any())


def _end_pairs(cfg: ModelConfig, estimate: SwarmEstimate, ends: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pairs (i, j), i of ``rows``, j != i (each pair once), with their contact probability when every robot stands at
    the end of a straight move from its estimate to ``ends`` (n, 2) (arrived, with the move's noise): the Gaussian
    relative position's probability of the disc (``disc_probability``) where the half-plane bound is over
    ``CONTACT_BOUND``, the bound elsewhere (it is under, and so is the probability)."""
    n = len(estimate.ids)
    moments = MotionMoments(cfg, estimate.positions, ends, estimate.cov, estimate.joint)
    if n < INDEX_MIN:
        i, j = all_pairs(rows, n)
    else:  # a pair whose mean positions are more than 2R + z (sd_i + sd_j) apart keeps the bound (``BodyCheck``)
        sd = moments.spread()
        pad = cfg.robot_radius_m + reach_sigmas(END_BOUND) * sd
        arrive = estimate.positions + moments.step
        i, j = near_pairs(rows, arrive, pad, arrive, pad)
    inside = np.zeros(n, bool)
    inside[rows] = True
    once = ~inside[j] | (j > i)
    i, j = i[once], j[once]
    ones = np.ones(len(i))
    return i, j, _pair_probability(cfg, moments, i, j, ones, ones)


def _yielding(i: np.ndarray, j: np.ndarray, can_i: np.ndarray, can_j: np.ndarray, length: np.ndarray) -> np.ndarray:
    """The robot of each pair (i, j) over the bound that gives way: of the two that can (``can_i``, ``can_j``, per
    pair), the one that would drive farther (``length``, m; ties: the higher index); -1 where neither can."""
    j_first = can_j & (~can_i | (length[j] > length[i]) | ((length[j] == length[i]) & (j > i)))
    return np.where(j_first, j, np.where(can_i, i, -1))


def safe_goals(cfg: ModelConfig, estimate: SwarmEstimate, goals: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``goals`` (n, 2) of the robots ``rows`` pulled back along their straight way where a pair would be at risk even
    standing there with the position uncertainty they have now (no motion: no approach helps it), and which were.
    A pair's robot with the longer way left (``_yielding``) steps back ``STOP_STEP`` of its way at a time until every
    pair of goals keeps ``CONTACT_BOUND`` or it is back where it stands (the pair's risk is then the start's own)."""
    current = estimate.positions
    path = goals - current
    length = np.hypot(*path.T)
    movable = np.zeros(len(current), bool)
    movable[rows] = length[rows] >= cfg.robot_radius_m  # a way shorter than a radius (a correction) is not pulled back
    fraction = np.ones(len(current))
    while True:  # fractions only fall, to 0 at most: this ends
        there = estimate.poses.copy()
        there[:, :2] = current + fraction[:, None] * path
        i, j, p = _end_pairs(cfg, SwarmEstimate(estimate.ids, there, estimate.cov, estimate.joint), there[:, :2], rows)
        i, j = i[p > CONTACT_BOUND], j[p > CONTACT_BOUND]
        can = movable & (fraction > 0)
        back = np.unique(_yielding(i, j, can[i], can[j], fraction * length))
        back = back[back >= 0]
        if not len(back):
            pulled = fraction < 1.0
            return np.where(pulled[:, None], there[:, :2], goals), pulled
        fraction[back] = np.maximum(fraction[back] - STOP_STEP, 0.0)


def _pair_probability(cfg: ModelConfig, moments: MotionMoments, i: np.ndarray, j: np.ndarray, at_i: np.ndarray,
                      at_j: np.ndarray) -> np.ndarray:
    """Contact probabilities of pairs (i, j) at one instant, each robot standing where it is (``at`` 0) or arrived at
    the end of its drive of ``moments`` (``at`` 1) with that drive's noise: the half-plane bound, and the Gaussian's
    disc probability itself where the bound says it may be over ``CONTACT_BOUND``."""
    zeros = np.zeros(len(i))
    mu, _, sigma, _, _ = moments.pairs(i, j, at_i, zeros, at_j, zeros)
    p = instant_bound(mu, sigma, 2.0 * cfg.robot_radius_m)
    over = np.flatnonzero(p > END_BOUND)
    p[over] = disc_probability(mu[over], sigma[over], 2.0 * cfg.robot_radius_m)
    return np.asarray(p)


def _waiting(cfg: ModelConfig, moments: MotionMoments, i: np.ndarray, j: np.ndarray, p: np.ndarray, rank: np.ndarray) -> list[int]:
    """Of each pair (i, j) of robots that could wait, over the bound at their leg's ends (contact probability ``p``;
    ``moments``: the leg's drives from where the robots stand to those ends), the robot that waits where it stands for
    the leg: the one of higher ``rank`` (n,) (a robot that could still stage before one on its last leg, then the longer
    way left, then the higher index), unless the other waiting keeps the pair's end within the bound and this does not,
    or keeps it lower. Pairs by falling ``p``; a robot is decided once
    (a pair with a robot already waiting or driving on for another pair is left to the next round)."""
    first = rank[i] > rank[j]
    wait, go = np.where(first, i, j), np.where(first, j, i)
    ones, zeros = np.ones(len(i)), np.zeros(len(i))
    mine = _pair_probability(cfg, moments, wait, go, zeros, ones)
    other = _pair_probability(cfg, moments, wait, go, ones, zeros)
    swap = (other < mine) & ((other <= CONTACT_BOUND) | (mine > CONTACT_BOUND))
    wait, go = np.where(swap, go, wait), np.where(swap, wait, go)
    decided: set[int] = set()
    out = []
    for k in np.argsort(-p, kind="stable"):
        a, b = int(wait[k]), int(go[k])
        if a not in decided and b not in decided:
            out.append(a)
            decided |= {a, b}
    return out


def _waits_too(cfg: ModelConfig, moments: MotionMoments, pairs: list[tuple[int, int]]) -> list[int]:
    """Of the pairs (r, h), robot r over the bound at its leg's end (``moments``: the leg's drives) against h, which
    waits: the robots r that wait too (they
    approach h standing, later), sorted; not one whose pair is at least as much at risk where both stand now as with r
    at its end (two robots the drives' error left touching both waiting stand touching: r drives)."""
    if not pairs:
        return []
    r, h = (np.array(x, np.int64) for x in zip(*pairs, strict=True))
    ones, zeros = np.ones(len(r)), np.zeros(len(r))
    helps = _pair_probability(cfg, moments, r, h, ones, zeros) < _pair_probability(cfg, moments, r, h, zeros, zeros)
    return sorted(set(r[~helps].tolist()))


def leg_targets(cfg: ModelConfig, estimate: SwarmEstimate, desired: np.ndarray, going: np.ndarray,
                last: bool | np.ndarray = False, final: bool = False) -> Leg:
    """The next leg of the robots ``going`` (n,) from ``estimate`` towards ``desired`` (n, 2) (module doc); ``last``
    (all or per robot, (n,)): the robot drives straight to its goal unless it waits; ``final``: every robot drives
    straight to its goal, none waits (one that would, over ``CONTACT_BOUND``, stops where it stands, and a robot over
    ``CONTACT_BOUND`` against one standing for the rest of the change stops short, as on a last leg). Robots not
    ``going`` stand where they are estimated.

    Each robot's goal is its desired position, pulled back where a pair is at risk there even with no motion
    (``safe_goals``: the robot stops short, ``Leg.short``). The leg's end configuration (every robot of ``going``
    arrived at its leg's end, with that drive's noise, the others where they stand) must keep every pair within
    ``END_BOUND`` (or ``FLOOR_FACTOR`` x the pair's own at its goals, at most ``CONTACT_BOUND``: ``limit``): both robots
    of a pair over it that can stage stop shorter (the next of ``LEG_FRACTIONS`` of
    their path), until none is over or they are at the shortest; against a robot that waits, an end is kept within the
    bound both where that one stands and at its goal (``_near_goals``). A pair still over is separated in time: of two
    robots that can wait (at their shortest or on their last leg) one waits where it stands (``_waiting``,
    ``Leg.held``), and one over against a neighbour that waits waits too (unless their pair is as much at risk
    standing: ``_waits_too``); the stops are then decided again from the start, until no such pair is left (a robot
    waits at most once: this ends). If nobody would drive, the robot whose leg's end is least at risk does (its highest
    pair probability; ties: a last leg, then the shorter way). A robot over
    at its shortest (or on its last leg) over ``CONTACT_BOUND`` against a robot that stands for the whole change, or
    whose way passes one over the steps' bound, drives the farthest part of its way, in ``STOP_STEP`` steps, whose end
    and way keep those bounds against every standing robot and goes on from there
    (staged), or ends the change there (on its last leg, or no step keeps it: it stays, ``Leg.short``); one over
    ``limit`` only (within ``CONTACT_BOUND``) at its shortest staging point against such a robot stages at the farthest
    such step whose end keeps ``limit``, where one does (``tried``: sought once a robot). Pairs whose
    goals are still at risk reached with no motion noise (pulled back to where they stand) are left out: no leg helps
    them."""
    current = estimate.positions
    desired = np.asarray(desired, float)[:, :2]
    going = np.asarray(going, bool)
    last = np.broadcast_to(np.asarray(last, bool) | final, going.shape)
    targets = np.where(going[:, None], desired, current)
    none = np.zeros(len(current), bool)
    rows = np.flatnonzero(going & (np.hypot(*(targets - current).T) >= MIN_LEG_M))
    if cfg.robot_radius_m <= 0 or not len(rows):
        return Leg(targets, none, none, none)
    targets, short = safe_goals(cfg, estimate, targets, rows)
    path = targets - current
    length = np.hypot(*path.T)
    drives = going & (length >= MIN_LEG_M)
    rows = np.flatnonzero(drives & ~last)
    waitable = drives
    if not drives.any():
        return Leg(targets, none, short, none)
    there = estimate.poses.copy()  # every robot standing at its goal with its position's uncertainty now, no motion
    there[:, :2] = targets
    i, j, p = _end_pairs(cfg, SwarmEstimate(estimate.ids, there, estimate.cov, estimate.joint), targets, np.flatnonzero(drives))
    hopeless = {(int(a), int(b)) for a, b in zip(i[p > CONTACT_BOUND], j[p > CONTACT_BOUND], strict=True)}
    own = p > END_BOUND / FLOOR_FACTOR
    allowed = {(min(a, b), max(a, b)): min(CONTACT_BOUND, FLOOR_FACTOR * q)
               for a, b, q in zip(i[own].tolist(), j[own].tolist(), p[own].tolist(), strict=True)}

    def limit(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """The contact probability pairs (a, b) may have at a leg's end: ``END_BOUND``, or up to ``FLOOR_FACTOR`` x
        their goals' own (no motion), at most ``CONTACT_BOUND``."""
        return np.array([allowed.get((min(x, y), max(x, y)), END_BOUND) for x, y in zip(a.tolist(), b.tolist(), strict=True)])
    fractions = np.array((1.0, *LEG_FRACTIONS))
    shortest = len(LEG_FRACTIONS)
    movable = np.zeros(len(current), bool)
    movable[rows] = True
    held = np.zeros(len(current), bool)
    order = np.lexsort((np.arange(len(current)), length, movable))  # a stager before a last leg, the longer way, the higher index
    rank = np.empty(len(current), np.int64)
    rank[order] = np.arange(len(current))

    cap = np.ones(len(current))  # the farthest fraction of its way a robot blocked by a standing one may drive
    tried = np.zeros(len(current), bool)  # robots whose staging point was sought within the end's bound against standing ones

    def stops() -> tuple[np.ndarray, np.ndarray, list[tuple[int, int, float]]]:
        """Each robot's level (0: straight to the goal, k: LEG_FRACTIONS[k - 1] of the way), the ends (at most ``cap``
        of the way), and the pairs over the bound at them (not hopeless), with the robots in ``held`` standing; a
        robot's end is also kept within the bound against a waiting robot standing at its goal (``_near_goals``)."""
        level = np.zeros(len(current), np.int64)
        while True:  # levels only grow, to ``shortest`` at most: this ends
            ends = current + np.where(held, 0.0, np.minimum(fractions[level], cap))[:, None] * path
            i, j, p = _end_pairs(cfg, estimate, ends, np.flatnonzero(drives))
            k = np.flatnonzero(p > END_BOUND)
            k = k[p[k] > limit(i[k], j[k])]  # a staging point is cheap: stop shorter over END_BOUND
            over = [(int(a), int(b), float(q)) for a, b, q in zip(i[k], j[k], p[k], strict=True) if (int(a), int(b)) not in hopeless]
            near = {r for a, b, _ in over for r in (a, b)} | _near_goals(cfg, estimate, ends, targets, held, drives, limit)
            shorter = sorted(r for r in near if movable[r] and not held[r] and level[r] < shortest)
            if not shorter:
                return level, ends, over
            level[shorter] += 1

    while True:  # caps only fall, ``STOP_STEP`` at a time, and a robot waits at most once a round: this ends
        held[:] = False
        while True:
            level, ends, over = stops()
            free = waitable & ~held  # at its shortest staging point or on its last leg, in every pair left over
            waits = [x for x in over if not final or x[2] > CONTACT_BOUND]  # in the last leg: over CONTACT_BOUND only
            pairs = [(a, b, q) for a, b, q in waits if free[a] and free[b]]
            beside = [(a, b) if free[a] else (b, a) for a, b, _ in waits if free[a] != free[b] and held[b if free[a] else a]]
            if not pairs and not beside:
                break
            moments = MotionMoments(cfg, estimate.positions, ends, estimate.cov, estimate.joint)  # the leg's drives to ``ends``
            alone = _waits_too(cfg, moments, beside)
            if not pairs and not alone:
                break
            held[alone] = True  # its neighbour waits: it approaches that one standing, later
            if pairs:
                a, b, q = (np.array(x) for x in zip(*pairs, strict=True))
                held[_waiting(cfg, moments, a, b, q, rank)] = True
        if held.any() and not (drives & ~held).any():  # nobody would drive: the one whose leg's end is least at risk does
            risk = []
            for r in order[held[order]]:  # a last leg first, then the shorter way: the first of equal risk drives
                held[r] = False
                risk.append((max((q for a, b, q in stops()[2] if r in (a, b)), default=0.0), r))
                held[r] = True
                if not risk[-1][0]:
                    break
            held[min(risk, key=lambda x: x[0])[1]] = False
            level, ends, over = stops()
        # over at its shortest (or on its last leg) against a robot standing for the rest of the change: a shorter leg
        on = drives & ~held if final else drives  # in the last leg a robot that would wait stands for good
        blocked = {b if on[b] else a for a, b, q in over if on[a] != on[b] and q > CONTACT_BOUND}
        blocked |= _passing_standing(cfg, estimate, ends, drives & ~held, on, drives & ~held)  # its way passes one: the same
        rows = np.array(sorted(r for r in blocked if not held[r] and cap[r] > 0), np.int64)
        # over the end's bound (within CONTACT_BOUND) at its shortest staging point against a standing robot: a shorter
        # staging point within it, where one is (tried once a robot; none: it stages there, as before)
        near = {b if on[b] else a for a, b, _ in over if on[a] != on[b]} - set(rows.tolist())
        strict = np.array(sorted(r for r in near if movable[r] and not held[r] and cap[r] > 0 and not tried[r]), np.int64)
        if not len(rows) and not len(strict):
            break
        if len(rows):
            reach = np.minimum(cap[rows], fractions[level[rows]])
            cap[rows] = _short_of_standing(cfg, estimate, ends, path, rows, reach, on, drives & ~held)
        if len(strict):
            tried[strict] = True
            reach = np.minimum(cap[strict], fractions[level[strict]])
            fraction = _short_of_standing(cfg, estimate, ends, path, strict, reach, on, drives & ~held, limit)
            cap[strict] = np.where(fraction > 0, fraction, cap[strict])
    capped = (cap < 1.0) & ~held
    stop = capped & (~movable | (cap == 0.0))  # its last leg, or no step keeps the bound: it ends the change there
    if final:  # a robot that would wait in the change's last leg ends the change where it stands
        stop |= held
        held[:] = False
    staged = ((level > 0) | capped) & ~held & ~stop
    targets[staged | stop] = ends[staged | stop]
    targets[held] = current[held]
    short = short | stop
    return Leg(targets, staged, short, held)


def contact_limit(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``CONTACT_BOUND`` for every pair (a, b): the bound a robot's end keeps against one standing for the change."""
    return np.full(len(a), CONTACT_BOUND)


def _short_of_standing(cfg: ModelConfig, estimate: SwarmEstimate, ends: np.ndarray, path: np.ndarray, rows: np.ndarray,
                       start: np.ndarray, drives: np.ndarray, going: np.ndarray,
                       bound: Callable[[np.ndarray, np.ndarray], np.ndarray] = contact_limit) -> np.ndarray:
    """(len(rows),) the farthest fraction of its ``path`` (n, 2) each robot of ``rows`` may drive, below ``start`` in
    steps of ``STOP_STEP``, whose end keeps ``bound`` (per pair; ``CONTACT_BOUND``) against every robot not of
    ``drives`` (standing for the rest of the change), and so does its way there (``_passing_standing``, against them and the robots of ``going``,
    which drive in the leg); 0 where none does (it stays where it stands). The others stand at ``ends`` (n, 2)."""
    fraction = np.zeros(len(rows))
    todo = np.ones(len(rows), bool)
    step = np.floor(start / STOP_STEP - 1e-9).astype(np.int64)  # the first fraction tried is below ``start``
    while todo.any() and (step[todo] > 0).any():  # steps only fall: this ends
        trying = todo & (step > 0)
        there = ends.copy()
        there[rows] = estimate.positions[rows] + (step * STOP_STEP)[:, None] * path[rows]
        i, j, p = _end_pairs(cfg, estimate, there, rows[trying])
        over = ~drives[j]
        over[over] = p[over] > bound(i[over], j[over])
        moving = np.zeros(len(there), bool)
        moving[rows[trying]] = True
        passing = np.array(sorted(_passing_standing(cfg, estimate, there, moving, drives, going)), np.int64)
        clear = trying & ~np.isin(rows, i[over]) & ~np.isin(rows, passing)
        fraction[clear] = step[clear] * STOP_STEP
        todo &= ~clear
        step[todo] -= 1
    return fraction


def _passing_standing(cfg: ModelConfig, estimate: SwarmEstimate, ends: np.ndarray, moving: np.ndarray,
                      drives: np.ndarray, going: np.ndarray) -> set[int]:
    """Robots of ``moving`` (n,) whose straight drive from where they stand to ``ends`` (n, 2) no order of the leg's
    steps keeps within the steps' bound: over it, all of them driving at once, against a robot not of ``drives``
    (standing for the rest of the change, where it stands: ``BodyCheck.step_conflicts``, the regrouping's verdict), or,
    driving alone, against a robot of ``going`` that drives less than a body radius in the leg (a correction: it all
    but stands) both where it stands and where it arrives (``BodyCheck.pair_risks``): whichever moves first, the drive
    passes it. The regrouping would move such a drive anyway, one at a time."""
    length = np.hypot(*(ends - estimate.positions).T)
    movers = moving & (length >= MIN_LEG_M)
    if not movers.any():
        return set()
    check = BodyCheck.of_estimate(cfg, estimate, ends)
    conflicts = check.step_conflicts(estimate.positions, movers)
    out = {c.a if movers[c.a] else c.b for c in conflicts if drives[c.a] != drives[c.b]}
    nearly = going & (length < cfg.robot_radius_m)
    if nearly.any():
        risks = check.pair_risks(np.flatnonzero(movers))
        start, end, _ = risks.over(check.robot_levels())
        out |= set(risks.i[start & end & nearly[risks.j]].tolist())
    return out


def _near_goals(cfg: ModelConfig, estimate: SwarmEstimate, ends: np.ndarray, goals: np.ndarray, held: np.ndarray,
                drives: np.ndarray, limit: Callable[[np.ndarray, np.ndarray], np.ndarray]) -> set[int]:
    """Robots of ``drives`` not ``held`` whose ``ends`` are over the bound against a ``held`` robot standing at its goal
    (of ``goals``) with the position uncertainty it has now: it goes there later, and an end that only keeps clear of
    where it waits may stand in its way or at its place (driven straight in while it waits, with the long drive's
    error)."""
    if not held.any():
        return set()
    there = estimate.poses.copy()
    there[held, :2] = goals[held]
    at = np.where(held[:, None], goals, ends)
    i, j, p = _end_pairs(cfg, SwarmEstimate(estimate.ids, there, estimate.cov, estimate.joint), at, np.flatnonzero(drives & ~held))
    over = (p > END_BOUND) & (held[i] != held[j])
    over[over] = p[over] > limit(i[over], j[over])
    return {int(r) for r in np.where(held[i[over]], j[over], i[over])}


@dataclass(frozen=True)
class LegRecord:
    """A leg as run: ``plan`` (its sub-steps; indices into ``ids``, the robots that drive in it), each robot's
    ``targets`` (len(ids), 2) m, which of them ``staged`` short of their desired position, how the body constraint
    split it (``regrouped``, None: clear as planned), ``held``: ids of the robots that wait where they stand in
    it (``Leg.held``; in a configuration's first leg they are in ``ids`` with their place as target: a zero command),
    ``groups_run``: the groups of ``plan`` executed (None: all; fewer when a step left two robots touching and
    the leg ended there, ``new_touches``, or its next step was at risk for all its robots), and ``deferred``: ids of
    robots whose group ran without them (their step was at risk, ``deferred_movers``: they go on in the next leg).
    ``plan`` stays the leg as planned and published."""

    plan: Plan
    ids: np.ndarray
    targets: np.ndarray
    staged: np.ndarray
    regrouped: Regrouping | None = None
    held: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    groups_run: int | None = None
    deferred: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))

    @property
    def staged_ids(self) -> np.ndarray:
        return np.asarray(self.ids[self.staged])

    @property
    def n_steps(self) -> int:
        """Steps the leg ran (its plan's, or fewer where it was cut short: ``after_step``)."""
        return self.plan.n_steps if self.groups_run is None else self.groups_run

    @property
    def cut(self) -> bool:
        """The leg ended before its plan's last group (at a touch, or before a step at risk for all its robots:
        ``after_step``)."""
        return self.n_steps < self.plan.n_steps

    @property
    def ran(self) -> np.ndarray:
        """(len(ids),) the robots that drove in the leg: those of the groups it ran (every group of a leg not cut) but
        the ``deferred`` ones."""
        out = np.zeros(len(self.ids), bool)
        out[self.plan.order[:sum(self.plan.sizes[:self.n_steps])]] = True
        return out & ~np.isin(self.ids, self.deferred)

    @property
    def going_on(self) -> np.ndarray:
        """Ids of the robots that go on in the next leg: staged short of their goal, waiting, or in a group the leg did
        not run (it ended at a touch), sorted."""
        return np.union1d(np.union1d(self.staged_ids, self.held), self.ids[~self.ran]).astype(np.int64)

    @property
    def base(self) -> Plan:
        """The plan the leg was cleared from (the strategy's, for a configuration's first leg)."""
        return self.plan if self.regrouped is None else self.regrouped.planned

    def n_anchors(self, n_robots: int) -> int:
        """Robots standing still in the leg's largest step, of a swarm of ``n_robots``."""
        return n_robots - min(self.plan.sizes)


def first_leg(cfg: ModelConfig, plan: Plan, estimate: SwarmEstimate, desired: np.ndarray) -> tuple[Plan, Regrouping | None, LegRecord | None]:
    """The strategy's ``plan`` (indices into ``estimate.ids``) cleared for bodies (``clear_plan``) towards the first
    leg's targets, how it was split, and the leg (None: every robot drives straight to ``desired``, and the plan is
    ``clear_plan``'s, bit for bit). Robots that wait in it keep their place in the plan with their place as target."""
    leg = leg_targets(cfg, estimate, desired, np.ones(len(estimate.ids), bool))
    if not leg.any:
        return (*clear_plan(cfg, plan, estimate, desired), None)
    cleared, regrouped = clear_plan(cfg, plan, estimate, leg.targets)
    return cleared, regrouped, LegRecord(cleared, estimate.ids, leg.targets, leg.staged, regrouped, estimate.ids[leg.held])


def step_at_risk(cfg: ModelConfig, estimate: SwarmEstimate, targets: np.ndarray, moving: np.ndarray,
                 moved: np.ndarray, known: np.ndarray | None = None) -> list[tuple[int, int]]:
    """The pairs (ids, sorted) over the steps' bound (``BodyCheck.step_conflicts``) when the step about to drive
    ``moving`` (n,) from ``estimate`` towards ``targets`` (n, 2) is judged against the robots of ``moved`` (n,), driven
    earlier in the same leg, where the new estimate puts them: the leg's regrouping judged the step with them at their
    planned ends, and a drive's error may have left one elsewhere, in the way. Pairs of two robots of ``known`` (n,;
    those the regrouping already could not clear) are left out. [] for point robots."""
    moving, moved = np.asarray(moving, bool), np.asarray(moved, bool) & ~np.asarray(moving, bool)
    if cfg.robot_radius_m <= 0 or not moving.any() or not moved.any():
        return []
    known = np.zeros(len(moving), bool) if known is None else np.asarray(known, bool)
    conflicts = BodyCheck.of_estimate(cfg, estimate, targets).step_conflicts(estimate.positions, moving)
    ids = estimate.ids
    return sorted((int(ids[c.a]), int(ids[c.b])) for c in conflicts
                  if (moved[c.a] or moved[c.b]) and not (known[c.a] and known[c.b]))


def deferred_movers(cfg: ModelConfig, estimate: SwarmEstimate, leg: LegRecord, k: int) -> np.ndarray:
    """Ids (sorted) of the robots of group k + 1 of ``leg``'s plan that do not drive in it: from ``estimate`` after its
    group k, their step towards the leg's targets is over the steps' bound against a robot the leg moved earlier, where
    the estimate now puts it (``step_at_risk``; ``known``: the leg's regrouping's ``unclear`` robots), or, the others of
    the group driving, against one of them standing where it is (until none is left: the leg's regrouping judged the
    group driving together). They stand and go on in the next leg (``LegRecord.deferred``). Empty after the leg's last
    group; the robots not in the leg stand."""
    plan, ids = leg.plan, leg.ids
    if k + 1 >= len(plan.groups) or cfg.robot_radius_m <= 0:
        return np.zeros(0, np.int64)
    present = np.isin(ids, estimate.ids)
    ends = estimate.positions.copy()
    ends[index_of(estimate.ids, ids[present], "leg")] = np.asarray(leg.targets, float)[present, :2]
    group = np.isin(estimate.ids, ids[plan.groups[k + 1]])
    moved = np.isin(estimate.ids, ids[leg.ran & np.isin(np.arange(len(ids)), np.concatenate(plan.groups[:k + 1]))])
    known = np.isin(estimate.ids, () if leg.regrouped is None else leg.regrouped.unclear)
    members = set(estimate.ids[group].tolist())
    held = {r for pair in step_at_risk(cfg, estimate, ends, group, moved, known) for r in pair if r in members}
    if not held:  # the common case: nothing more to judge
        return np.zeros(0, np.int64)
    check = BodyCheck.of_estimate(cfg, estimate, ends)
    while True:  # held grows to the whole group at most: this ends
        standing = np.isin(estimate.ids, list(held))
        driving = group & ~standing
        more = {int(estimate.ids[c.a if driving[c.a] else c.b]) for c in check.step_conflicts(estimate.positions, driving)
                if standing[c.a] or standing[c.b]} - held if driving.any() else set()
        if not more:
            return np.array(sorted(held), np.int64)
        held |= more


def corrections(cfg: ModelConfig, estimate: SwarmEstimate, desired: np.ndarray, going: np.ndarray) -> np.ndarray:
    """(n,) the robots not ``going`` on that stand over ``CONTACT_BOUND`` against a neighbour by ``estimate`` (both
    where they stand now, no motion) and would be at most half as much at risk at their goal (``desired`` (n, 2),
    pulled back as ``safe_goals`` does; the drive's noise counted, the neighbour where it stands): they drive a
    **correction** towards it in the next leg instead of standing there for the rest of the change. Pairs of two
    robots going on are left to their legs."""
    n = len(estimate.ids)
    out = np.zeros(n, bool)
    if cfg.robot_radius_m <= 0:
        return out
    current = estimate.positions
    i, j, p = _end_pairs(cfg, estimate, current, np.arange(n))
    over = (p > CONTACT_BOUND) & ~(going[i] & going[j])
    if not over.any():
        return out
    i, j, p = i[over], j[over], p[over]
    rows = np.setdiff1d(np.concatenate([i, j]), np.flatnonzero(going))
    goals = current.copy()
    goals[rows] = np.asarray(desired, float)[rows, :2]
    goals, _ = safe_goals(cfg, estimate, goals, rows)
    away = np.hypot(*(goals - current).T) >= MIN_LEG_M
    moments = MotionMoments(cfg, current, np.where(away[:, None], goals, current), estimate.cov, estimate.joint)
    ones, zeros = np.ones(len(i)), np.zeros(len(i))
    for a, b in ((i, j), (j, i)):  # each robot of a pair at its goal, the other where it stands
        better = _pair_probability(cfg, moments, a, b, ones, zeros) <= 0.5 * p
        out[a[better & away[a] & ~going[a]]] = True
    return out


def driven_legs(legs: tuple[LegRecord, ...], ids: np.ndarray) -> np.ndarray:
    """(len(ids),) the legs of ``legs`` each robot of ``ids`` drove in (was in a group the leg ran and did not wait)."""
    return np.asarray(sum((np.isin(ids, leg.ids[leg.ran]) & ~np.isin(ids, leg.held)).astype(np.int64) for leg in legs))


def new_touches(cfg: ModelConfig, before: SwarmEstimate, after: SwarmEstimate,
                moved: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The pairs a step left touching, at which the leg ends (``coordinator.executor``; ``swarm replay --check``
    recomputes it): ids (a, b), a < b, sorted, and their contact probability, of every pair whose standing contact
    probability by the estimate ``after`` the step (both where they stand, no motion: ``_end_pairs``, as
    ``corrections``) is over ``CONTACT_BOUND``, at least one of whose robots moved in the step (``moved``: ids), and
    which was not over it by the estimate ``before`` the step (a pair left at risk by design, e.g. goals too close,
    is no new touch). Robots not in both estimates are left out; none for point robots."""
    none = np.zeros(0, np.int64)
    if cfg.robot_radius_m <= 0:
        return none, none, np.zeros(0)
    after = after.select(np.isin(after.ids, before.ids))
    rows = np.flatnonzero(np.isin(after.ids, moved))
    if not len(rows):
        return none, none, np.zeros(0)
    i, j, p = _end_pairs(cfg, after, after.positions, rows)
    over = p > CONTACT_BOUND
    a, b = np.minimum(after.ids[i[over]], after.ids[j[over]]), np.maximum(after.ids[i[over]], after.ids[j[over]])
    p = p[over]
    if not len(p):
        return none, none, np.zeros(0)
    prior = before.select(np.isin(before.ids, np.union1d(a, b)))  # the pairs' robots: a pair's risk is its own
    k, m, q = _end_pairs(cfg, prior, prior.positions, np.arange(len(prior.ids)))
    ids = prior.ids
    was = q > CONTACT_BOUND
    width = int(max(a.max(), b.max())) + 1
    fresh = ~np.isin(a * width + b, np.minimum(ids[k[was]], ids[m[was]]) * width + np.maximum(ids[k[was]], ids[m[was]]))
    order = np.lexsort((b[fresh], a[fresh]))
    return a[fresh][order], b[fresh][order], p[fresh][order]


def after_step(cfg: ModelConfig, legs: tuple[LegRecord, ...], leg: LegRecord, k: int, before: SwarmEstimate,
               after: SwarmEstimate, moved: np.ndarray) -> tuple[tuple[LegRecord, ...], str | None]:
    """The change's legs after group ``k`` of ``leg``'s plan ran, and why that leg ended there (None: it did not);
    ``legs``: the change's legs so far, ``leg`` the last of them, or, for a change without legs (``legs`` = ()), its
    plan as a first leg to the desired positions; ``moved``: ids of the robots the step drove, ``before`` and ``after``
    its estimates. Where the step left two robots touching (``new_touches``) the leg ends there (after its last group
    too for a change without legs, so that ``next_leg`` parts them); where robots of the next group are at risk against
    robots the leg moved earlier (``deferred_movers``) they stand in it (``LegRecord.deferred``), and where that is the
    whole group the leg ends there. Nothing for point robots, after a leg's last group, or in the change's
    ``LEG_CAP``-th leg. The executor and ``swarm replay --check`` both decide here."""
    last = k + 1 == len(leg.plan.groups)
    if cfg.robot_radius_m <= 0 or len(legs) >= LEG_CAP or (legs and last):
        return legs, None
    a, b, p = new_touches(cfg, before, after, moved)
    if len(a):
        why = ", ".join(f"robots {x} and {y} touching ({q:.3g})" for x, y, q in zip(a.tolist(), b.tolist(), p.tolist(), strict=True))
        return (*legs[:-1], replace(leg, groups_run=None if last else k + 1)), why
    deferred = deferred_movers(cfg, after, leg, k)
    if not len(deferred):
        return legs, None
    group = np.intersect1d(leg.ids[leg.plan.groups[k + 1]], after.ids)
    if np.isin(group, deferred).all():
        return (*legs[:-1], replace(leg, groups_run=k + 1)), f"robots {group.tolist()} at risk in its next step"
    return (*legs[:-1], replace(leg, deferred=np.union1d(leg.deferred, deferred).astype(np.int64))), None


def next_leg(cfg: ModelConfig, legs: tuple[LegRecord, ...], estimate: SwarmEstimate, desired: np.ndarray,
             index: int) -> LegRecord | None:
    """Leg ``index`` (>= 1) of the robots that go on after ``legs`` (the change's legs so far; those lost since are
    left out) from ``estimate`` towards ``desired`` (rows of ``estimate.ids``): the strategy's plan (the first leg's
    ``base``) kept to the robots that drive in it, in its order (but groups with a robot of a pair standing over
    ``CONTACT_BOUND`` now first, so the pair parts in the leg's first steps), consecutive groups merged while they move at most as
    many robots as its largest group (so every step keeps at least the plan's anchors), its targets from
    ``leg_targets`` (a robot's ``MAX_LEGS``-th driven leg and the change's ``LEG_CAP``-th leg straight to the targets),
    the groups cleared for bodies (``BodyCheck.regroup``); robots that wait in it are not in its plan (``held``), nor
    robots it stops where they stand (``Leg.short``). Robots that stand at risk after the legs so far drive a correction
    (``corrections``). None when none of them is left to drive."""
    first = legs[0]
    going = np.isin(estimate.ids, legs[-1].going_on)
    fix = corrections(cfg, estimate, desired, going)
    mask = going | fix
    if not mask.any():
        return None
    last = mask & (driven_legs(legs, estimate.ids) >= MAX_LEGS - 1)
    leg = leg_targets(cfg, estimate, desired, mask, last, final=index >= LEG_CAP - 1)
    moved = (leg.targets != estimate.positions).any(axis=1)
    drive = mask & ~leg.held & (moved | leg.staged)  # a robot its leg stops where it stands is left out of the leg
    if not drive.any():
        return None
    ids = estimate.ids[drive]
    rows = np.flatnonzero(drive)
    base, base_ids = first.base, first.ids
    row_of = {int(r): k for k, r in zip(rows, ids, strict=True)}
    kept = [np.array([row_of[int(r)] for r in base_ids[g] if int(r) in row_of], np.int64) for g in base.groups]
    i, j, p = _end_pairs(cfg, estimate, estimate.positions, rows)  # pairs with a robot of the leg standing at risk now
    touching = np.union1d(i[p > CONTACT_BOUND], j[p > CONTACT_BOUND])
    kept.sort(key=lambda g: not np.isin(g, touching).any())  # stable: their groups first, so the pair parts at once
    groups: list[np.ndarray] = []  # consecutive groups merged while they move no more robots than the plan's largest group
    for g in (g for g in kept if len(g)):
        if groups and len(groups[-1]) + len(g) <= max(base.sizes):
            groups[-1] = np.concatenate([groups[-1], g])
        else:
            groups.append(g)
    out = BodyCheck.of_estimate(cfg, estimate, leg.targets).regroup(groups)
    local = np.searchsorted(ids, estimate.ids[np.concatenate(out.groups)])
    plan = Plan(local, tuple(len(g) for g in out.groups))
    planned = Plan(np.searchsorted(ids, estimate.ids[np.concatenate(groups)]), tuple(len(g) for g in groups))
    same = len(out.groups) == len(groups) and all(np.array_equal(a, b) for a, b in zip(out.groups, groups, strict=True))
    regrouped = None if same else Regrouping(planned, tuple(int(r) for r in estimate.ids[out.unclear]), out.bound)
    return LegRecord(plan, ids, leg.targets[rows], leg.staged[rows], regrouped, estimate.ids[leg.held])
