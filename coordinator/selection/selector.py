"""Outer loop of the anchor selection (Section 4.2.1, Fig. 6): the number of anchors.

For every feasible anchor count n_a (Eq. 7) the inner loop finds the anchors R_a*(n_a)
with the least expected localization error e_l (Eq. 9), seeded by the heuristic
(Eq. 11-13). Then P_v = 1 / n_s (Eq. 1, 6), P_l = e_l / e_l(0) (Eq. 2, with
e_l,max = e_l(0), the error with no anchors) and P_s = w_v P_v - w_l P_l (Eq. 3);
the selection maximises P_s over the plans that keep the swarm connected (Eq. 4).

Search, per selection (``docs/selection.md`` has the budgets and the measurements):

1. Screening: every feasible n_a with at most ``max_steps`` steps (all of them up to
   n_r = 10) is scored with its heuristic plan on one Monte Carlo
   set of common random numbers (``samples_for(samples)`` samples), a crowded plan (bodies
   too close) too: its e_l bounds its count's, though it is not a plan to return.
2. Bound: the inner loop of a count can only lower its e_l; a count is searched unless
   even ``prune_gain`` less e_l than its heuristic plan's would leave its P_s below the
   bar: the best screened P_s of a clear plan, raised by each searched count's kept plan
   (on the screening samples); counts are searched most promising first (every count whose
   P_s could win is searched, Section 4.2.1). A searched count's crowded heuristic plan is
   repaired by a few single swaps (``repair``); the result is its seed.
3. Inner loop of every surviving count, where ``genetic_runs`` (else the count keeps its seed,
   scored on the screening samples): the genetic search on the screening samples (more of them
   for a count with more than 252 plans, ``search_samples``), with the joint localizer its new plans
   screened by the Cramer-Rao prediction (``screens``: only the best-predicted few of each
   generation are evaluated by Monte Carlo, ``GeneticConfig.screened``), then a race
   (successive halving on fresh samples, clearly worse contenders dropped early, a large round judged after
   its first half too, ``RACE_LOOKS``) among its ``contenders``
   (screened: ``screened_contenders``) best distinct plans (a race won by the seed ends there: the seed keeps
   its screened score; so does a count whose race leader's P_s is clearly below the best of the other
   counts, ``cannot_win``: it cannot win, so no final check is spent on it), then
   the race winner and the seed on one more fresh set
   (``samples_for(final_samples)``, seen in ``final_looks`` looks that stop once the paired
   difference is decided, ``racing.final_check``, or once neither plan can win: the seed is kept as screened):
   the winner replaces the seed only if it is better by
   more than one standard error of the paired difference; the kept plan's fresh e_l and
   e_l(0) on the same samples give P_l. So the search never returns a plan that is worse
   than its seed on those samples, and P_s is not biased by the search. A count without a seed has its race
   winner scored on the fresh set after every count's search, look by look until its P_s is decided against
   the other counts' (``decided``). A count whose every feasible plan is a start of the search and a contender
   of the race is raced without the search (it could find nothing new). Every budget is a
   number of evaluations, never a time: a selection is a function of its seed.

Bodies (constraint g of Eq. 4, ``docs/bodies.md``): a plan is feasible only if it also keeps
every step's nominal motion clear of collisions (``runtime.models.bodies.BodyCheck``), for the
heuristic seeds, the genetic search and the outer loop alike (judged from its pair verdicts,
``clear_pairs``). A searched count whose heuristic plan is crowded runs the genetic search wherever the gate
is not ``off`` (the repair makes a plan clear, not good):
from its repaired plan and, when the count has at most ``ENUMERATED`` plans, its clear plans of the least
predicted e_l (Cramer-Rao, ``crlb_rank``). A count whose search met no clear plan takes every clear plan of a
small count (all evaluated, then raced as the search's), or, with one mover a step, an order of single moves
that keeps each clear (``BodyCheck.ordered_moves``). A search from enumerated clear plans races ``contenders`` of them
(screened or not) from a quarter of the final check's samples: its best plans are often 3-5 % apart, which the search's
few samples cannot order. When no plan found is clear but
some keep the swarm connected, the connected heuristic plan with the fewest steps is returned
and the executor splits its conflicting steps.

Readings of the Monte Carlo (``docs/experiments.md``, pre-registered): ``mc_start`` is where
each simulated configuration change starts (``"estimate"``: truths drawn from the estimate's
covariance; ``"known"``: at its mean, Sec. 4.2), ``mc_emax`` what e_l,max is (``"mean"``: the
mean over samples of e_l(0), Sec. 4.1.1; ``"worst"``: the largest e_l(0) over the samples).

``method = "crlb"`` ranks plans by the Cramer-Rao prediction of ``crlb_rank`` instead
(deterministic, no sampling, so no race and no final check).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from functools import partial

import numpy as np

from coordinator.localization import Localizer
from coordinator.plan import Plan, enumerate_plans, feasible_anchor_counts, n_solutions, n_steps, speed_performance
from coordinator.selection.clear_pairs import PairTable
from coordinator.selection.crlb_rank import predicted_error, predicted_errors
from coordinator.selection.genetic import GeneticConfig, genetic_search
from coordinator.selection.heuristic import heuristic_plan
from coordinator.selection.monte_carlo import MC_STARTS, MonteCarlo, plan_keeps_connectivity
from coordinator.selection.racing import EARLY_MARGIN, best_distinct, final_check, fresh_blocks, race
from coordinator.selection.repair import repair
from runtime.errors import SwarmInputError
from runtime.models.bodies import BodyCheck
from runtime.models.config import ModelConfig
from runtime.models.state import SwarmEstimate

METHODS = ("mc", "crlb")
GENETIC_GATES = ("auto", "on", "off")  # the genetic search: where it was measured to beat its seed, always, never
# Where the genetic search beat its seed (``genetic_pays``): (localizer, with bodies) -> {measured n_r: (fewest, most) steps n_s}
GENETIC_PAYS: dict[tuple[str, bool], dict[int, tuple[int, int]]] = {
    ("paper", True): {10: (1, 10)},
    ("paper", False): {10: (1, 10)},  # it also beat its seed at 30 and 100 points, at 3-200 s a count: off (docs)
    ("joint", True): {10: (5, 10)},
    ("joint", False): {10: (10, 10)},
}
MEASURED_SIZES = (10, 30, 100)  # n_r of the measurement; a swarm takes the row of the nearest (by ratio)
SCREENED_LOCALIZERS = ("joint",)  # the genetic search screens its plans by the Cramer-Rao prediction (``screens``)
MC_EMAX = ("mean", "worst")  # e_l,max: mean over the samples of e_l(0), or their largest
ENUMERATED = 5040  # plans of a count enumerated for a clear one when the genetic search met none (n_r = 8: n_a = 4, 6)
RACE_LOOKS = 8  # a race's round of at least 2 x final samples / this is seen in two halves (``racing.race``'s ``look``)
ENUMERATED_RACE = 4  # a race among enumerated clear plans starts at final samples / this (8 contenders: the last 2 get all of them)


class NoFeasiblePlanError(SwarmInputError):
    """No anchor count and choice keeps every robot observable after every step."""


@dataclass(frozen=True)
class SelectionConfig:
    """Weights of Eq. 3 and the search budget."""

    w_v: float = 0.5
    w_l: float = 0.5
    samples: int = 16  # Monte Carlo samples per candidate for a 10-robot swarm (see ``samples_for``)
    genetic: GeneticConfig = field(default_factory=GeneticConfig)
    anchor_counts: tuple[int, ...] | None = None  # None = every feasible n_a (Eq. 7)
    final_samples: int = 256  # samples of the final fresh check for 10 robots (scaled like ``samples``)
    contenders: int = 8  # best distinct plans of the genetic search that enter the race
    screened_contenders: int = 2  # ... of a search screened by prediction (``screens``: at most 21 plans were sampled)
    final_looks: int = 4  # looks of the sequential final check (``racing.fresh_blocks``); 1 = one fixed set
    prune_gain: float = 0.25  # a count is searched if its P_s with this much less e_l could win
    method: str = "mc"  # "mc": Monte Carlo e_l; "crlb": Cramer-Rao prediction (no sampling)
    window: int = 100  # larger swarms: the Monte Carlo simulates this many robots, heuristic plans only (``docs/selection.md``)
    max_steps: int = 10  # counts with more steps n_s are not screened unless ``anchor_counts`` names them
    mc_start: str = "known"  # Monte Carlo start: one of ``MC_STARTS`` (``docs/experiments.md``: the text's reading)
    mc_emax: str = "mean"  # e_l,max: one of ``MC_EMAX``
    genetic_gate: str = "auto"  # one of ``GENETIC_GATES``: where the genetic search runs (``genetic_pays``)

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise SwarmInputError(f"selection method must be one of {', '.join(METHODS)}, got {self.method!r}")
        if self.mc_start not in MC_STARTS or self.mc_emax not in MC_EMAX:
            raise SwarmInputError(f"Monte Carlo start must be one of {', '.join(MC_STARTS)} and e_l,max one of "
                                  f"{', '.join(MC_EMAX)}, got {self.mc_start!r}, {self.mc_emax!r}")
        if self.genetic_gate not in GENETIC_GATES:
            raise SwarmInputError(f"genetic search must be one of {', '.join(GENETIC_GATES)}, got {self.genetic_gate!r}")
        if self.mc_emax == "worst" and self.method != "mc":
            raise SwarmInputError("e_l,max 'worst' needs Monte Carlo samples: use it with the mc selection, not crlb")
        if min(self.final_samples, self.contenders, self.screened_contenders, self.final_looks) < 1 or not 0 <= self.prune_gain <= 1:
            raise SwarmInputError(
                f"final samples, contenders and final looks must be >= 1 and prune gain in [0, 1], got "
                f"{self.final_samples}, {self.contenders}/{self.screened_contenders}, {self.final_looks}, {self.prune_gain}"
            )
        if not (self.w_v >= 0 and self.w_l >= 0 and abs(self.w_v + self.w_l - 1.0) < 1e-9):
            raise SwarmInputError(f"weights must be >= 0 and sum to 1 (Eq. 3), got w_v={self.w_v}, w_l={self.w_l}")
        if self.samples < 1:
            raise SwarmInputError(f"Monte Carlo samples must be >= 1, got {self.samples}")
        if self.window < 2 or self.max_steps < 1:
            raise SwarmInputError(f"window must be >= 2 robots and max steps >= 1, got {self.window}, {self.max_steps}")


def samples_for(samples: int, n_robots: int) -> int:
    """Monte Carlo samples for ``n_robots``: ``samples`` x 10 / n_r, at least 2.

    e_l (Eq. 8) averages over the robots, so its Monte Carlo standard error falls like
    1 / sqrt(samples x n_r); keeping samples x n_r constant keeps the precision of the
    comparison between plans while a 100-robot selection stays affordable.
    """
    return max(2, -(-samples * 10 // n_robots))


def genetic_pays(localizer: str, n_robots: int, n_anchors: int, cfg: ModelConfig) -> bool:
    """Whether the genetic search beat its heuristic seed by more than the Monte Carlo's noise (2 standard errors of
    the paired difference on fresh samples) in at least one case in eight, pooled over motion noise x 1 and x 3,
    where it was measured (``swarm study selection --genetic-gain``, docs/selection.md): per localizer, bodies
    (radius > 0) or point robots, and swarm size (the measured size nearest ``n_robots`` by ratio), the range of
    steps n_s (Eq. 7) where it did. Localizers or sizes not in ``GENETIC_PAYS``: off (not measured; or, for 30 and
    100 point robots with the paper's localizer, paying 1-6 % of e_l at 3-200 s a count, too slow to be online)."""
    rows = GENETIC_PAYS.get((localizer, cfg.robot_radius_m > 0), {})
    size = min(MEASURED_SIZES, key=lambda m: abs(math.log(n_robots / m)))
    if size not in rows:
        return False
    fewest, most = rows[size]
    return fewest <= n_steps(n_robots, n_anchors) <= most


REFERENCE_PLANS = 252  # plans of n_a = 5 at n_r = 10: counts with more get more search samples
MAX_SEARCH_SCALE = 2.0  # at most twice the screening samples


def search_samples(samples: int, plans: int) -> int:
    """Monte Carlo samples of the genetic search and race of a count with ``plans`` plans (Eq. 10).

    ``samples`` (the screening samples) x ln(plans) / ln(``REFERENCE_PLANS``), between 1x and
    ``MAX_SEARCH_SCALE`` x. The best of N noisy estimates is biased low by about
    sqrt(2 ln N) standard errors (the winner's curse) and the standard error falls like
    1 / sqrt(samples), so samples growing like ln N keep that bias from growing with the plan
    space. n_r = 8: n_a = 4 (70 plans) keeps 20, n_a = 6 (2520) gets 29, n_a = 7 (40320) 39.
    """
    scale = min(MAX_SEARCH_SCALE, max(1.0, math.log(plans) / math.log(REFERENCE_PLANS)))
    return math.ceil(samples * scale - 1e-9)


@dataclass(frozen=True)
class CountScore:
    """Outer-loop entry for one anchor count."""

    n_anchors: int
    e_l: float
    p_v: float
    p_l: float
    p_s: float
    plan: Plan | None
    seed_e_l: float = float("nan")  # e_l of the heuristic seed on the same samples as ``e_l``
    searched: bool = False  # the count passed the outer-loop bound and its inner loop ran (else: the heuristic plan, screened)
    crowded: bool = False  # no plan: its heuristic plan brings bodies too close (docs/bodies.md) and no clear plan was found
    genetic: bool = False  # the genetic search (with race and final check) ran for this count (``genetic_runs``)
    seed: Plan | None = None  # the plan the inner loop started from: the heuristic plan, repaired for bodies (``repair``)


@dataclass(frozen=True)
class Selection:
    plan: Plan
    scores: list[CountScore]
    evaluations: int
    fresh_seed: int | None = None  # Monte Carlo seed of the final check (its blocks: ``racing.fresh_blocks``)

    @property
    def n_anchors(self) -> int:
        return self.plan.n_anchors


class AnchorSelector:
    """Online selection of (n_a, R_a)* for each configuration change (Section 4).

    ``localizer`` is the executor's localizer object: the Monte Carlo simulates exactly it, options included.
    """

    def __init__(self, cfg: ModelConfig, localizer: Localizer, selection: SelectionConfig, seed: int) -> None:
        self.cfg = cfg
        self.localizer = localizer
        self.selection = selection
        self.seed = seed
        self.calls = 0

    def candidate_counts(self, n: int) -> list[int]:
        """The given counts, or every feasible n_a (Eq. 7) with at most ``max_steps`` steps."""
        feasible = feasible_anchor_counts(n)
        if self.selection.anchor_counts is None:
            return [n_a for n_a in feasible if n_steps(n, n_a) <= self.selection.max_steps]
        bad = [k for k in self.selection.anchor_counts if k not in feasible]
        if bad:
            raise SwarmInputError(f"anchor counts {bad} are not feasible for {n} robots; feasible: {feasible} (Eq. 7)")
        return list(self.selection.anchor_counts)

    def select(self, estimate: SwarmEstimate, desired: np.ndarray) -> Selection:
        """The plan maximising P_s for moving from ``estimate`` to ``desired`` positions (n, 2)."""
        n, sel = estimate.n, self.selection
        self.calls += 1
        rng = np.random.default_rng([self.seed, self.calls])
        if n > sel.window:
            return self._select_large(estimate, desired, rng)
        samples, final_samples = samples_for(sel.samples, n), samples_for(sel.final_samples, n)
        current = estimate.positions
        bodies = BodyCheck.of_estimate(self.cfg, estimate, desired)
        pairs = PairTable(bodies)  # the same verdicts for every plan judged, from a few steps (``clear_pairs``)

        checked: dict[bytes, bool] = {}  # connectivity of the step configurations seen (plans share them)

        def connected(plan: Plan) -> bool:
            return plan_keeps_connectivity(plan, current, desired, self.cfg.sensing_range_m, checked)

        def is_clear(plan: Plan) -> bool:
            return bool(pairs.clear([plan])[0])

        def feasible(plan: Plan) -> bool:
            return is_clear(plan) and connected(plan)

        def sampled(plans: list[Plan], count: int, seed: int) -> np.ndarray:
            return MonteCarlo(self.cfg, self.localizer, count, seed, sel.mc_start).localization_errors(estimate, desired, plans)

        def each_sample(plans: list[Plan], count: int, seed: int) -> np.ndarray:
            return MonteCarlo(self.cfg, self.localizer, count, seed, sel.mc_start).localization_errors(estimate, desired, plans, per_sample=True)

        screen_seed = int(rng.integers(2**63))
        if sel.method == "crlb":
            def evaluate(plans: list[Plan]) -> np.ndarray:
                return predicted_errors(self.cfg, estimate, desired, plans)
        else:
            def evaluate(plans: list[Plan]) -> np.ndarray:
                return sampled(plans, samples, screen_seed)

        def score(n_a: int, plan: Plan | None, e_l: float, e_max: float, seed_e_l: float = np.nan, searched: bool = False,
                  crowded: bool = False, genetic: bool = False) -> CountScore:
            p_v = speed_performance(n, n_a)
            p_l = e_l / e_max if e_max > 0 else 0.0
            return CountScore(n_a, float(e_l), p_v, float(p_l), float(sel.w_v * p_v - sel.w_l * p_l), plan, float(seed_e_l), searched,
                              crowded, genetic)

        all_move = Plan.equal(np.arange(n), 0)
        seeds = {n_a: all_move if n_a == 0 else heuristic_plan(current, desired, n_a) for n_a in self.candidate_counts(n)}
        screened_plans = [n_a for n_a in seeds if n_a != 0 and connected(seeds[n_a])]
        if sel.method == "crlb":  # e_l(0) = e_l,max: one deterministic prediction
            e_zero = e_max = float(evaluate([all_move])[0])
            e_seeds = evaluate([seeds[k] for k in screened_plans])
        else:  # e_l(0) (e_l,max: the mean over the samples, Section 4.1.1, or ``worst``, their largest) and every count's
            # heuristic plan on the screening samples, in one pass (``block_errors``)
            per = each_sample([all_move] + [seeds[k] for k in screened_plans], samples, screen_seed)
            e_zero, e_max = float(per[0].mean()), float(per[0].max() if sel.mc_emax == "worst" else per[0].mean())
            e_seeds = per[1:].mean(axis=1)
        e_seed_of = dict(zip(screened_plans, e_seeds.tolist(), strict=True))
        evaluations = 1 + len(screened_plans)
        scores: dict[int, CountScore] = {}
        for n_a in seeds:  # 1. screening: the heuristic plan of every count
            if not connected(seeds[n_a]):
                scores[n_a] = score(n_a, None, np.inf, e_max)
            elif n_a == 0:
                scores[n_a] = score(n_a, all_move, e_zero, e_max, crowded=not is_clear(all_move))
            else:  # a crowded seed (bodies too close) is screened too: its e_l bounds the count's (step 2)
                e_seed = e_seed_of[n_a]
                scores[n_a] = score(n_a, seeds[n_a], e_seed, e_max, e_seed, crowded=not is_clear(seeds[n_a]))
        screened = {k: s.p_s for k, s in scores.items()}  # P_s on the screening samples (the crowded too)
        # the best P_s each count has shown (its clear screened plan, then its kept plan on the screening samples)
        reached = {k: s.p_s for k, s in scores.items() if s.plan is not None and not s.crowded}

        def bar(other_than: int | None = None) -> float:
            return max((p for k, p in reached.items() if k != other_than), default=-np.inf)

        def raise_bar(n_a: int, p_s: float) -> None:
            reached[n_a] = max(reached.get(n_a, -np.inf), p_s)
        for k, s in list(scores.items()):  # a crowded count keeps no plan unless its inner loop finds a clear one
            if s.crowded:
                scores[k] = replace(s, plan=None, e_l=np.inf, p_l=np.inf, p_s=-np.inf)
        final_seed = int(rng.integers(2**63))
        blocks = fresh_blocks(final_samples, final_seed, sel.final_looks)
        no_anchor_blocks: list[np.ndarray] = []  # e_l(0) per sample of each fresh block, as far as a final check looked

        def fresh_emax(looked: int) -> float:
            """e_l,max on the first ``looked`` blocks of the fresh set (the kept plan's e_l is on the same samples)."""
            while len(no_anchor_blocks) < looked:
                no_anchor_blocks.append(each_sample([all_move], *blocks[len(no_anchor_blocks)])[0])
            per = np.concatenate(no_anchor_blocks[:looked])
            return float(per.max() if sel.mc_emax == "worst" else per.mean())

        def fresh_look(plans: list[Plan], count: int, seed: int) -> np.ndarray:
            """A look of the final check at a fresh block, with e_l(0) on the block in the same pass where ``fresh_emax``
            has not seen it yet (it reads the blocks the check looked at)."""
            if len(no_anchor_blocks) < len(blocks) and blocks[len(no_anchor_blocks)] == (count, seed):
                per = each_sample([*plans, all_move], count, seed)
                no_anchor_blocks.append(per[-1])
                return per[:-1]
            return each_sample(plans, count, seed)

        race_no_anchor: dict[tuple[int, int], np.ndarray] = {}  # e_l(0) per sample of each race block (samples, seed)

        def race_emax(blocks: list[tuple[int, int]]) -> float:
            """e_l,max on a race's blocks (its plans' e_l are on the same samples)."""
            for b in blocks:
                if b not in race_no_anchor:
                    race_no_anchor[b] = each_sample([all_move], *b)[0]
            per = np.concatenate([race_no_anchor[b] for b in blocks])
            return float(per.max() if sel.mc_emax == "worst" else per.mean())

        def cannot_win(n_a: int, e_l: np.ndarray, e_l_max: Callable[[], float]) -> bool:
            """Whether a plan of ``n_a`` anchors with e_l per sample ``e_l`` (e_l,max on the same samples: ``e_l_max()``)
            cannot win: its P_s (Eq. 3) is below the best of the other counts by more than ``EARLY_MARGIN`` standard errors."""
            other = bar(other_than=n_a)
            if not np.isfinite(other) or len(e_l) < 2:  # no other count has a plan, or no spread to judge by
                return False
            p_s = sel.w_v * speed_performance(n, n_a) - sel.w_l * e_l / e_l_max()
            return bool(p_s.mean() + EARLY_MARGIN * p_s.std(ddof=1) / np.sqrt(len(p_s)) < other)

        def decided(n_a: int, e_l: np.ndarray, e_l_max: float, other: float) -> bool:
            """Whether a plan of ``n_a`` anchors with e_l per sample ``e_l`` on the fresh set is decided against ``other``, the
            best P_s (Eq. 3) of the other counts: more than ``EARLY_MARGIN`` standard errors below or above it."""
            if len(e_l) < 2:
                return False
            p_s = sel.w_v * speed_performance(n, n_a) - sel.w_l * e_l / e_l_max
            return bool(abs(p_s.mean() - other) > EARLY_MARGIN * p_s.std(ddof=1) / np.sqrt(len(p_s)))
        pending: list[int] = []  # seedless counts whose race winner waits for its fresh check (after every count's search)
        # 2. bound and 3. inner loop, most promising count first; the bar rises with each count's kept plan
        for n_a in sorted((k for k in scores if k != 0), key=lambda k: (-self._optimistic(screened[k], scores[k].p_v), k)):
            if self._optimistic(screened[n_a], scores[n_a].p_v) < bar():
                continue
            seed = repair(seeds[n_a], pairs, connected) if connected(seeds[n_a]) else None
            # a crowded heuristic plan: its repair only makes a plan clear, so the count is searched wherever the search may run
            genetic = self.genetic_runs(n, n_a) or (scores[n_a].crowded and sel.genetic_gate != "off")
            if not genetic:  # gated off (``genetic_runs``): the count's plan is its (repaired) heuristic plan
                if seed is None:
                    scores[n_a] = replace(scores[n_a], searched=True)
                    continue
                e_seed = scores[n_a].seed_e_l if seed is seeds[n_a] else float(evaluate([seed])[0])
                evaluations += seed is not seeds[n_a]
                scores[n_a] = replace(score(n_a, seed, e_seed, e_max, e_seed, searched=True), seed=seed)
                raise_bar(n_a, scores[n_a].p_s)
                continue
            starts = [seed] if seed is not None else [seeds[n_a]]
            clear = self._clear_plans(n, n_a, pairs, connected) if scores[n_a].crowded else None
            if clear:  # clear plans are few and far from the heuristic's: the search starts from the best-predicted
                ranked = [clear[k] for k in np.argsort(predicted_errors(self.cfg, estimate, desired, clear), kind="stable")]
                starts = ([seed] if seed is not None else []) + [p for p in ranked if seed is None or p.key() != seed.key()]
                starts = starts[: sel.genetic.population]
            known = {seed.key(): scores[n_a].seed_e_l} if seed is seeds[n_a] else {}
            screen = self.screens()  # Monte Carlo only for the best-predicted plans
            plans = n_solutions(n, n_a)
            if screen:  # plans compared by Monte Carlo: seeds + 2 x screened + screened a generation
                plans = min(plans, len(starts) + sel.genetic.screened * (sel.genetic.generations + 2))
            count_samples = samples if sel.method == "crlb" else search_samples(samples, plans)
            search = evaluate
            if count_samples != samples:  # many plans compared: more samples (the seed's screened e_l is not on them)
                known, search = {}, partial(sampled, count=count_samples, seed=screen_seed)
            predict = partial(predicted_errors, self.cfg, estimate, desired) if screen else None
            settled: list[Plan] | None = None  # the race's contenders when the search is not run
            plan: Plan | None
            if sel.method != "crlb" and clear and len(starts) <= sel.contenders and {p.key() for p in clear} <= {p.key() for p in starts}:
                # every feasible plan of the count is a start and the race takes them all: the search can find nothing new
                plan, e_l, settled = starts[0], np.nan, list(starts)
            else:
                plan, e_l, k = genetic_search(search, starts, feasible, rng, sel.genetic, known, predict)
                evaluations += k
            found: list[Plan] | None = None  # every clear plan of the count, evaluated when the search met none
            if plan is None:  # no clear plan met: every clear plan of a small count, or an order of single moves
                found = self._clear_plans(n, n_a, pairs, connected) if clear is None else clear
                if not found and n - n_a == 1:
                    moves, unclear = bodies.ordered_moves(np.arange(n), np.zeros(n, bool), np.arange(n))
                    single = Plan(np.concatenate(moves), (1,) * n) if not unclear and len(moves) == n else None
                    found = [single] if single is not None and feasible(single) else []
                if found:
                    known.update((p.key(), float(e)) for p, e in zip(found, search(found), strict=True))
                    plan = min(found, key=lambda p: known[p.key()])
                    evaluations += len(found)
            if plan is None:
                scores[n_a] = replace(scores[n_a], searched=True, genetic=True)
                continue
            if sel.method == "crlb":  # elitism: never above the seed's prediction
                scores[n_a] = replace(score(n_a, plan, e_l, e_max, scores[n_a].seed_e_l, searched=True, genetic=True), seed=seed)
                raise_bar(n_a, scores[n_a].p_s)
                continue
            # a search from enumerated clear plans (few, far apart, all of a population sampled): as many contenders as an
            # unscreened search, and a race whose last round has the final check's samples (``ENUMERATED_RACE``)
            enumerated = bool(clear) or bool(found)
            contenders = sel.contenders if enumerated or not screen else sel.screened_contenders
            race_samples = max(count_samples, -(-final_samples // ENUMERATED_RACE)) if enumerated else count_samples
            no_anchor_seen = len(race_no_anchor)

            def hopeless(e_l: np.ndarray, seen: list[tuple[int, int]], n_a: int = n_a) -> bool:
                return cannot_win(n_a, e_l, partial(race_emax, seen))

            def race_round(plans: list[Plan], count: int, seed: int, rivals: bool = bool(np.isfinite(bar(other_than=n_a)))) -> np.ndarray:
                """A round's e_l per sample, with e_l(0) on its samples in the same pass where ``hopeless`` will read it
                (``cannot_win``: where another count has a plan)."""
                if (count, seed) in race_no_anchor or not rivals:
                    return each_sample(plans, count, seed)
                per = each_sample([*plans, all_move], count, seed)
                race_no_anchor[(count, seed)] = per[-1]
                return per[:-1]
            raced = race(settled or best_distinct(known, contenders), race_round, race_samples, rng, hopeless=hopeless,
                         look=-(-final_samples // RACE_LOOKS))
            champion, evaluations = raced.winner, evaluations + raced.spent + len(race_no_anchor) - no_anchor_seen
            if raced.stopped and seed is None:  # cannot win: scored on the race's samples, no final check
                scores[n_a] = score(n_a, champion, float(raced.e_l.mean()), race_emax(raced.blocks), searched=True, genetic=True)
                continue
            decision: tuple[Plan, float, float, int] | None = None  # a final check's (kept, e_l, seed e_l, looks)
            futile: list[int] = []  # the looks of a final check stopped because neither plan can win
            if seed is not None and not raced.stopped and champion.key() != seed.key():

                def neither(e_l: np.ndarray, looked: int, n_a: int = n_a, futile: list[int] = futile) -> bool:
                    futile[:] = [looked] if cannot_win(n_a, e_l, partial(fresh_emax, looked)) else []
                    return bool(futile)
                decision = final_check(champion, seed, fresh_look, final_samples, final_seed, looks=sel.final_looks, hopeless=neither)
                evaluations += 2 * decision[3]
            if seed is not None and (decision is None or futile):  # the seed, scored as screened (no final check or a futile one)
                if seed is seeds[n_a] or (count_samples == samples and seed.key() in known):
                    e_seed = scores[n_a].seed_e_l if seed is seeds[n_a] else known[seed.key()]
                else:
                    e_seed = float(evaluate([seed])[0])
                    evaluations += 1
                scores[n_a] = replace(score(n_a, seed, e_seed, e_max, e_seed, searched=True, genetic=True), seed=seed)
                raise_bar(n_a, scores[n_a].p_s)
                continue
            if seed is None:  # no feasible seed: the race winner's fresh check waits until every count has its plan
                pending.append(n_a)
                on_screen = known.get(champion.key()) if count_samples == samples else None
                if on_screen is None:
                    on_screen = float(evaluate([champion])[0])
                    evaluations += 1
                scores[n_a] = score(n_a, champion, on_screen, e_max, searched=True, genetic=True)
                raise_bar(n_a, scores[n_a].p_s)
                continue
            assert decision is not None  # a seed, and a final check that decided
            kept, e_fresh, e_seed, looked = decision
            scores[n_a] = replace(score(n_a, kept, e_fresh, fresh_emax(looked), e_seed, searched=True, genetic=True), seed=seed)
            on_screen = known.get(kept.key()) if count_samples == samples else None
            if on_screen is None:
                on_screen = float(evaluate([kept])[0])
                evaluations += 1
            raise_bar(n_a, score(n_a, kept, on_screen, e_max).p_s)
        for n_a in pending:  # the seedless race winners on the fresh set, block by block until decided against the others'
            # P_s (a seedless count not yet looked at: its winner on the screening samples)
            winner, each = scores[n_a].plan, []
            assert winner is not None  # a race winner
            other = max((scores[j].p_s for j in scores if j != n_a and scores[j].plan is not None), default=-np.inf)
            for b in blocks:
                each.append(fresh_look([winner], *b)[0])
                if decided(n_a, np.concatenate(each), fresh_emax(len(each)), other):
                    break
            evaluations += 2 * len(each)
            scores[n_a] = score(n_a, winner, float(np.concatenate(each).mean()), fresh_emax(len(each)), searched=True, genetic=True)
        ordered = [scores[k] for k in sorted(scores)]
        best = max((s for s in ordered if s.plan is not None), key=lambda s: s.p_s, default=None)
        if best is None:
            crowded = [seeds[k] for k in sorted(seeds, key=lambda k: seeds[k].n_steps) if connected(seeds[k])]
            if crowded:  # connected but every plan found brings bodies too close: the fewest steps, split by the executor
                return Selection(crowded[0], ordered, evaluations)
            raise NoFeasiblePlanError(
                f"no anchor plan keeps every robot within sensing range {self.cfg.sensing_range_m} m of another "
                f"after every step (tried n_a = {sorted(scores)})"
            )
        assert best.plan is not None  # chosen among the plans found
        return Selection(best.plan, ordered, evaluations, final_seed if no_anchor_blocks else None)

    def _select_large(self, estimate: SwarmEstimate, desired: np.ndarray, rng: np.random.Generator) -> Selection:
        """Selection for n_r > ``window`` with a budget that does not grow with n_r (``docs/selection.md``).

        Approximations: (1) e_l is the Monte Carlo mean over the ``window`` robots nearest the
        centroid of the current estimate, simulated without the rest of the swarm
        (``samples_for(samples, window)`` samples; ``crlb`` predicts the same window);
        (2) each count's plan is its heuristic plan (Eq. 11-13), not searched (Eq. 9);
        (3) as for every n_r, counts with more than ``max_steps`` steps are not screened. Exact: counts are
        screened by increasing n_s and one with w_v P_v below the best P_s so far is skipped
        (P_l >= 0, so it cannot win). ``scores`` lists the screened counts.
        """
        n, sel = estimate.n, self.selection
        current = estimate.positions
        window = np.zeros(n, bool)
        window[np.argsort(np.linalg.norm(current - current.mean(axis=0), axis=1), kind="stable")[: sel.window]] = True
        if sel.method == "crlb":
            sub, sub_desired = estimate.select(window), desired[window]

            def evaluate(plan: Plan) -> float:
                steps = np.stack([plan.moving(k) for k in range(plan.n_steps)])
                return predicted_error(self.cfg, sub, sub_desired, steps[:, window])
        else:
            mc = MonteCarlo(self.cfg, self.localizer, samples_for(sel.samples, sel.window), int(rng.integers(2**63)), sel.mc_start)

            def evaluate(plan: Plan) -> float:
                return float(mc.localization_errors(estimate, desired, [plan], window=window)[0])

        all_move = Plan.equal(np.arange(n), 0)
        if sel.method == "crlb":
            e_zero = e_max = evaluate(all_move)
        else:
            per = mc.localization_errors(estimate, desired, [all_move], per_sample=True, window=window)[0]
            e_zero, e_max = float(per.mean()), float(per.max() if sel.mc_emax == "worst" else per.mean())
        bodies = BodyCheck.of_estimate(self.cfg, estimate, desired)
        scores: list[CountScore] = []
        crowded: list[Plan] = []  # connected plans that bring bodies too close, by increasing n_s
        bar = -np.inf
        for n_a in self.candidate_counts(n):
            p_v = speed_performance(n, n_a)
            if sel.w_v * p_v < bar:
                continue
            plan = all_move if n_a == 0 else heuristic_plan(current, desired, n_a)
            if not plan_keeps_connectivity(plan, current, desired, self.cfg.sensing_range_m):
                scores.append(CountScore(n_a, np.inf, p_v, np.inf, -np.inf, None))
                continue
            if not bodies.is_clear(plan.groups):
                crowded.append(plan)
                scores.append(CountScore(n_a, np.inf, p_v, np.inf, -np.inf, None, crowded=True))
                continue
            e_l = e_zero if n_a == 0 else evaluate(plan)
            p_l = e_l / e_max if e_max > 0 else 0.0
            scores.append(CountScore(n_a, e_l, p_v, p_l, sel.w_v * p_v - sel.w_l * p_l, plan, e_l))
            bar = max(bar, scores[-1].p_s)
        best = max((s for s in scores if s.plan is not None), key=lambda s: s.p_s, default=None)
        if best is None and crowded:
            return Selection(crowded[0], scores, len(scores))
        if best is None:
            raise NoFeasiblePlanError(
                f"no anchor plan with at most {sel.max_steps} steps keeps every robot within sensing range "
                f"{self.cfg.sensing_range_m} m of another after every step (tried n_a = {[s.n_anchors for s in scores]})"
            )
        assert best.plan is not None  # chosen among the plans found
        return Selection(best.plan, scores, len(scores))

    @staticmethod
    def _clear_plans(n: int, n_a: int, pairs: PairTable, connected: Callable[[Plan], bool]) -> list[Plan] | None:
        """Every feasible plan (clear and connected) of ``n_a`` anchors when the count has at most ``ENUMERATED`` plans,
        else None."""
        if n_solutions(n, n_a) > ENUMERATED:
            return None
        plans = enumerate_plans(n, n_a)
        return [p for p, ok in zip(plans, pairs.clear(plans), strict=True) if ok and connected(p)]

    def _optimistic(self, p_s: float, p_v: float) -> float:
        """The count's P_s if its inner loop lowered the screened e_l by ``prune_gain`` (Section 4.2.1's bound;
        w_v P_v, i.e. P_l = 0, when its heuristic plan broke connectivity and nothing was measured)."""
        if not np.isfinite(p_s):
            return self.selection.w_v * p_v
        return p_s + self.selection.prune_gain * (self.selection.w_v * p_v - p_s)

    def screens(self) -> bool:
        """Whether the genetic search screens its plans by the Cramer-Rao prediction (``GeneticConfig.screened`` > 0):
        only with the Monte Carlo and a localizer in ``SCREENED_LOCALIZERS``, whose errors the prediction ranks
        (the joint localizer reaches the bound; the paper's stays 1.5-2.7x above it and ranks plans otherwise:
        screened, its search lost quality in ``swarm study selection``, docs/selection.md)."""
        sel = self.selection
        return sel.method == "mc" and sel.genetic.screened > 0 and self.localizer.name in SCREENED_LOCALIZERS

    def genetic_runs(self, n: int, n_a: int) -> bool:
        """Whether the genetic search runs for ``n_a`` of ``n`` robots (``SelectionConfig.genetic_gate``; ``auto``: where
        ``genetic_pays``, and always with ``crlb``, whose deterministic prediction needs no race and no final check)."""
        gate, sel = self.selection.genetic_gate, self.selection
        return gate == "on" or (gate == "auto" and (sel.method == "crlb" or genetic_pays(self.localizer.name, n, n_a, self.cfg)))
