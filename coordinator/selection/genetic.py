"""Inner optimisation loop (Section 4.2.2, Eq. 9): genetic search over ordered partitions.

A candidate is a permutation of the robots cut into the plan's consecutive mobile
groups. Order crossover (OX1) of two permutations is again a permutation, and a
mutation swaps two robots of different groups, so every child is a valid partition.
The population is seeded with the heuristic plan (Eq. 11-13) and random plans; when the
count has more plans than the search can visit (``population`` x (``generations`` + 1)),
the first generation also holds ``swaps`` distinct single swaps of the heuristic plan
(two robots of different groups exchanged): random permutations of a large plan space
(2520 plans at n_r = 8, n_a = 6) rarely come near the optimum, which is mostly near the
heuristic plan, while in a small one they cover most of it and the swaps only narrow the
search (measurements in ``docs/selection.md``);
the fitness is the Monte Carlo e_l on common random numbers, evaluated once per
distinct partition (cached) and for a whole generation in one vectorised batch.

Screening (``predict``, the Cramer-Rao prediction of ``crlb_rank``, no sampling): of each
generation's new plans only the ``screened`` with the lowest prediction (``2 x screened`` in the
first generation, besides the seeds) are evaluated by Monte Carlo; the others get a surrogate
fitness, their prediction x the median ratio of Monte Carlo e_l to prediction over the plans
evaluated so far, so they can still be parents, but the search returns and the caller races
only Monte Carlo-evaluated plans. The budget is fixed in evaluations, not in time, so a search
is a function of its random numbers.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from coordinator.plan import Plan, PlanKey, n_partitions


@dataclass(frozen=True)
class GeneticConfig:
    population: int = 12
    generations: int = 8
    patience: int = 3  # generations without improvement before stopping
    elite: int = 2
    mutation: float = 0.4  # probability that a child gets one swap
    swaps: int = 6  # single swaps of the seed added to the first generation of a large plan space (``covers``)
    screened: int = 2  # with a predictor: new plans per generation evaluated by Monte Carlo (twice as many in the first)

    def covers(self, plans: int) -> bool:
        """Whether the search can visit ``plans`` plans (then no swaps are added)."""
        return plans <= self.population * (self.generations + 1)


def order_crossover(a: np.ndarray, b: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """OX1: a slice of ``a`` kept in place, the rest filled in ``b``'s order."""
    n = len(a)
    i, j = sorted(rng.choice(n + 1, 2, replace=False))
    child = np.full(n, -1)
    child[i:j] = a[i:j]
    rest = b[~np.isin(b, a[i:j])]
    child[np.flatnonzero(child < 0)] = rest
    return child


def swap_mutation(order: np.ndarray, sizes: tuple[int, ...], rng: np.random.Generator) -> np.ndarray:
    """Swap two robots that belong to different groups (no-op for a single group)."""
    group_of = np.repeat(np.arange(len(sizes)), sizes)
    if len(sizes) < 2:
        return order
    i = int(rng.integers(len(order)))
    j = int(rng.choice(np.flatnonzero(group_of != group_of[i])))
    out = order.copy()
    out[i], out[j] = out[j], out[i]
    return out


def single_swaps(plan: Plan, count: int, rng: np.random.Generator) -> list[Plan]:
    """Up to ``count`` distinct plans that each swap two robots of different groups of ``plan``
    (all of them, in random order, when there are at most ``count``)."""
    group_of = np.repeat(np.arange(len(plan.sizes)), plan.sizes)
    i, j = np.triu_indices(len(plan.order), 1)
    pairs = np.flatnonzero(group_of[i] != group_of[j])  # different groups: a different partition
    out = []
    for k in rng.permutation(pairs)[:count]:
        order = plan.order.copy()
        order[i[k]], order[j[k]] = order[j[k]], order[i[k]]
        out.append(Plan(order, plan.sizes))
    return out


def genetic_search(
    evaluate: Callable[[list[Plan]], np.ndarray],
    seeds: list[Plan],
    feasible: Callable[[Plan], bool],
    rng: np.random.Generator,
    cfg: GeneticConfig = GeneticConfig(),
    known: dict[PlanKey, float] | None = None,
    predict: Callable[[list[Plan]], np.ndarray] | None = None,
) -> tuple[Plan | None, float, int]:
    """Best plan found, its e_l, and the number of distinct plans newly evaluated.

    ``evaluate`` maps plans to e_l (lower is better); infeasible plans get e_l = inf.
    ``known`` holds e_l already computed on the same random numbers, by ``Plan.key()``;
    when given, every newly evaluated plan is added to it (the caller races the best of them).
    ``predict`` (a cheap prediction of e_l, same order as ``evaluate``) screens each generation's
    new plans: only ``cfg.screened`` of them are evaluated (module docstring); the seeds always are.
    Returns (None, inf, k) when no feasible plan was found.
    """
    sizes = seeds[0].sizes
    n = seeds[0].n_robots
    cache: dict[PlanKey, float] = known if known is not None else {}
    preset = len(cache)
    guessed: dict[PlanKey, float] = {}  # surrogate fitness of screened-out plans (``predict``)
    predicted: dict[PlanKey, float] = {}

    def score(plans: list[Plan], limit: int | None = None, always: tuple[Plan, ...] = ()) -> np.ndarray:
        """Fitness of ``plans``: the new feasible ones evaluated (with a predictor and a ``limit``, the ``limit`` best
        predicted, the others guessed); ``always``: plans evaluated whatever their prediction (the seeds), in the
        same Monte Carlo pass."""
        fresh: list[Plan] = []
        first: list[Plan] = []  # of ``always``
        seen: set[PlanKey] = set()
        for k, p in enumerate((*always, *plans)):
            key = p.key()
            if key in cache or key in seen:
                continue
            seen.add(key)
            if not feasible(p):
                cache[key] = np.inf
            else:
                (first if k < len(always) else fresh).append(p)
        if predict is not None and limit is not None and len(fresh) > limit:
            unknown = [p for p in fresh if p.key() not in predicted]
            if unknown:
                predicted.update((p.key(), float(e)) for p, e in zip(unknown, predict(unknown), strict=True))
            fresh = sorted(fresh, key=lambda p: predicted[p.key()])  # stable: ties keep the generation's order
            fresh, rest = fresh[:limit], fresh[limit:]
        else:
            rest = []
        fresh = first + fresh
        if fresh:
            for p, e in zip(fresh, evaluate(fresh), strict=True):
                cache[p.key()] = float(e)
                guessed.pop(p.key(), None)
        if rest:
            ratios = [cache[k] / predicted[k] for k in predicted if k in cache and np.isfinite(cache[k]) and predicted[k] > 0]
            ratio = float(np.median(ratios)) if ratios else 1.0
            guessed.update((p.key(), predicted[p.key()] * ratio) for p in rest)
        return np.array([cache[p.key()] if p.key() in cache else guessed[p.key()] for p in plans])

    def measured_best() -> float:
        return min((e for e in cache.values() if np.isfinite(e)), default=np.inf)

    population = list(seeds)
    while len(population) < cfg.population:
        population.append(Plan(rng.permutation(n), sizes))
    if not cfg.covers(n_partitions(sizes)):
        population += single_swaps(seeds[0], cfg.swaps, rng)
    fitness = score(population, 2 * cfg.screened, tuple(seeds) if predict is not None else ())  # the seeds are always evaluated
    best, stale = measured_best(), 0
    for _ in range(cfg.generations):
        order = np.argsort(fitness, kind="stable")
        children = [population[k] for k in order[: cfg.elite]]
        while len(children) < cfg.population:
            a, b = (population[min(rng.choice(len(population), 2, replace=False), key=lambda k: fitness[k])] for _ in range(2))
            child = order_crossover(a.order, b.order, rng)
            if rng.random() < cfg.mutation:
                child = swap_mutation(child, sizes, rng)
            children.append(Plan(child, sizes))
        population, fitness = children, score(children, cfg.screened)
        current = measured_best()
        stale = 0 if current < best else stale + 1
        best = min(best, current)
        if stale >= cfg.patience:
            break
    if predict is None:
        k = int(np.argmin(fitness))
        if not np.isfinite(fitness[k]):
            return None, np.inf, len(cache) - preset
        return population[k], float(fitness[k]), len(cache) - preset
    keys = [k for k, e in cache.items() if np.isfinite(e)]  # Monte Carlo-evaluated only
    if not keys:
        return None, np.inf, len(cache) - preset
    key = min(keys, key=lambda k: cache[k])
    return Plan(np.concatenate([np.asarray(g, dtype=np.int64) for g in key]), tuple(len(g) for g in key)), cache[key], len(cache) - preset
