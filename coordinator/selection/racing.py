"""Choosing among noisy candidates without fooling ourselves (Section 4.2.2, Eq. 9).

The genetic search ranks plans by Monte Carlo e_l on one set of common random numbers;
its best plan is partly the plan that was luckiest on those draws, and its e_l is
biased low (the minimum of noisy estimates). Two steps remove that:

* ``race``: successive halving over the search's best distinct plans on fresh sample
  blocks (common random numbers within a block, the budget doubling each round),
  keeping the better half by the mean over every block seen so far;
* ``final_check``: the race's winner and the search's seed (the heuristic plan,
  Eq. 11-13) re-evaluated on one more fresh set; the better of the two is kept with
  that fresh e_l, so the selection never does worse than its seed on those samples
  and P_s (Eq. 3) is computed from an e_l that took no part in choosing the plan
  among the search's candidates.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from coordinator.plan import Plan

Evaluator = Callable[[list[Plan], int, int], np.ndarray]  # (plans, samples, seed) -> e_l (m) per plan


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


def final_check(champion: Plan, seed: Plan, evaluate: Evaluator, samples: int, fresh: int) -> tuple[Plan, float, float]:
    """(kept plan, its e_l, the seed's e_l) on the fresh set of ``samples`` drawn from seed ``fresh``; the seed wins ties."""
    if champion.key() == seed.key():
        e_seed = float(evaluate([seed], samples, fresh)[0])
        return seed, e_seed, e_seed
    e_champion, e_seed = (float(v) for v in evaluate([champion, seed], samples, fresh))
    return (champion, e_champion, e_seed) if e_champion < e_seed else (seed, e_seed, e_seed)


def best_distinct(cache: dict[tuple, float], count: int) -> list[Plan]:
    """The ``count`` plans with the lowest finite e_l in a ``Plan.key()`` -> e_l cache."""
    ranked = sorted((e, key) for key, e in cache.items() if np.isfinite(e))[:count]
    return [Plan(np.concatenate([np.asarray(g, dtype=np.int64) for g in key]), tuple(len(g) for g in key)) for _, key in ranked]
