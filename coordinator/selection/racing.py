"""Choosing among noisy candidates without fooling ourselves (Section 4.2.2, Eq. 9).

The genetic search ranks plans by Monte Carlo e_l on one set of common random numbers;
its best plan is partly the plan that was luckiest on those draws, and its e_l is
biased low (the minimum of noisy estimates). Two steps remove that:

* ``race``: successive halving over the search's best distinct plans on fresh sample
  blocks (common random numbers within a block, the budget doubling each round),
  keeping the better half by the mean over every block seen so far;
* ``final_check``: the race's winner and the search's seed (the heuristic plan,
  Eq. 11-13) re-evaluated on one more fresh set; the winner replaces the seed only if
  it is better there by more than ``margin`` standard errors of the paired per-sample
  difference (a one-sided paired test), so the selection never does worse than its
  seed on those samples and rarely on others; P_s (Eq. 3) is computed from the kept
  plan's e_l on that set, which took no part in choosing among the search's candidates.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from coordinator.plan import Plan

Evaluator = Callable[[list[Plan], int, int], np.ndarray]  # (plans, samples, seed) -> e_l (m) per plan
SampleEvaluator = Callable[[list[Plan], int, int], np.ndarray]  # (plans, samples, seed) -> e_l (m) per plan and sample
MARGIN = 1.0  # standard errors by which a challenger must beat the seed in the final check


def race(plans: list[Plan], evaluate: Evaluator, samples: int, rng: np.random.Generator) -> tuple[Plan, int]:
    """Winner of successive halving over ``plans`` and the number of plan evaluations spent.

    Round r evaluates the survivors on ``samples`` x 2^r fresh samples (one new seed per
    round, shared by the survivors) and keeps the better half by the sample-weighted mean.
    """
    alive = list(range(len(plans)))
    total = np.zeros(len(plans))
    weight = np.zeros(len(plans))
    spent, budget = 0, samples
    while len(alive) > 1:
        e_l = evaluate([plans[k] for k in alive], budget, int(rng.integers(2**63)))
        total[alive] += e_l * budget
        weight[alive] += budget
        spent += len(alive)
        keep = max(1, len(alive) // 2)
        alive = sorted(alive, key=lambda k: (total[k] / weight[k], k))[:keep]
        budget *= 2
    return plans[alive[0]], spent


def final_check(champion: Plan, seed: Plan, evaluate: SampleEvaluator, samples: int, fresh: int,
                margin: float = MARGIN) -> tuple[Plan, float, float]:
    """(kept plan, its e_l, the seed's e_l) on the fresh set of ``samples`` drawn from seed ``fresh``.

    The champion is kept only if its mean e_l is below the seed's by more than ``margin``
    standard errors of the per-sample difference (common random numbers pair the samples).
    """
    if champion.key() == seed.key():
        e_seed = float(evaluate([seed], samples, fresh)[0].mean())
        return seed, e_seed, e_seed
    each = evaluate([champion, seed], samples, fresh)
    diff = each[0] - each[1]
    e_champion, e_seed = float(each[0].mean()), float(each[1].mean())
    se = float(diff.std(ddof=1) / np.sqrt(len(diff))) if len(diff) > 1 else 0.0
    return (champion, e_champion, e_seed) if diff.mean() + margin * se < 0 else (seed, e_seed, e_seed)


def best_distinct(cache: dict[tuple, float], count: int) -> list[Plan]:
    """The ``count`` plans with the lowest finite e_l in a ``Plan.key()`` -> e_l cache."""
    ranked = sorted((e, key) for key, e in cache.items() if np.isfinite(e))[:count]
    return [Plan(np.concatenate([np.asarray(g, dtype=np.int64) for g in key]), tuple(len(g) for g in key)) for _, key in ranked]
