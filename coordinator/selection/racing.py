"""Choosing among noisy candidates without fooling ourselves (Section 4.2.2, Eq. 9).

The genetic search ranks plans by Monte Carlo e_l on one set of common random numbers;
its best plan is partly the plan that was luckiest on those draws, and its e_l is
biased low (the minimum of noisy estimates). Two steps remove that:

* ``race``: successive halving over the search's best distinct plans on fresh sample
  blocks (common random numbers within a block, the budget doubling each round),
  keeping the better half by the mean over every block seen so far, less the contenders that
  are already clearly worse than the leader (``clearly_worse``: a paired test on every sample
  seen): the race ends as soon as one is left, or once even its leader is clearly below the best
  P_s (Eq. 3) of the other counts (the selector's ``hopeless``: no final check is spent on a count that cannot win);
* ``final_check``: the race's winner and the search's seed (the heuristic plan,
  Eq. 11-13) re-evaluated on one more fresh set; the winner replaces the seed only if
  it is better there by more than ``margin`` standard errors of the paired per-sample
  difference (a one-sided paired test), so the selection never does worse than its
  seed on those samples and rarely on others; P_s (Eq. 3) is computed from the kept
  plan's e_l on that set, which took no part in choosing among the search's candidates.
  With ``looks`` > 1 the set is drawn in blocks (``fresh_blocks``: a quarter, a quarter, a half for
  3 looks) and the check stops at an interim look once the paired difference is decided by
  ``EARLY_MARGIN`` standard errors either way (a sequential test: an undecided difference goes on
  to the next block, and the last look applies ``margin``); e_l is then over the blocks seen.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from coordinator.plan import Plan, PlanKey

SampleEvaluator = Callable[[list[Plan], int, int], np.ndarray]  # (plans, samples, seed) -> e_l (m) per plan and sample
MARGIN = 1.0  # standard errors by which a challenger must beat the seed in the final check
EARLY_MARGIN = 2.0  # standard errors that decide the paired difference at an interim look of the final check


class RaceResult(NamedTuple):
    winner: Plan
    spent: int  # plan evaluations
    stopped: bool  # ``hopeless`` ended the race: the winner cannot win the outer loop
    e_l: np.ndarray  # the winner's e_l per sample over every block seen
    blocks: list[tuple[int, int]]  # (samples, seed) of each round


def race(plans: list[Plan], evaluate: SampleEvaluator, samples: int, rng: np.random.Generator,
         margin: float = EARLY_MARGIN, hopeless: Callable[[np.ndarray, list[tuple[int, int]]], bool] | None = None,
         look: int | None = None) -> RaceResult:
    """Successive halving over ``plans``.

    Round r evaluates the survivors on ``samples`` x 2^r fresh samples (one new seed per round,
    shared by the survivors), so every survivor has been seen on the same samples. After each round
    a contender whose mean e_l exceeds the leader's (the lowest mean) by more than ``margin``
    standard errors of their paired per-sample difference is clearly worse and drops out (at most
    the worse half stays out too: plain halving); the race ends when one is left, or as soon as
    ``hopeless`` (the leader's e_l per sample, the blocks seen) says even the leader cannot win.
    With ``look``, a round of at least 2 x ``look`` samples is seen in two halves (the second from a seed derived
    from the round's): the clearly worse drop out and ``hopeless`` is asked after the first half too.
    """
    alive = list(range(len(plans)))
    seen = np.zeros((len(plans), 0))  # e_l per sample of every round so far (the survivors' rows are filled)
    blocks: list[tuple[int, int]] = []
    spent, budget = 0, samples
    while len(alive) > 1:
        round_seed = int(rng.integers(2**63))
        halves = look is not None and budget >= 2 * look
        parts = [(budget // 2, round_seed), (budget - budget // 2, int(np.random.default_rng([round_seed, 1]).integers(2**63)))]
        for part, block in enumerate(parts if halves else [(budget, round_seed)]):
            blocks.append(block)
            each = evaluate([plans[k] for k in alive], *block)
            seen = np.concatenate([seen, np.zeros((len(plans), block[0]))], axis=1)
            seen[alive, -block[0]:] = each
            spent += len(alive)
            alive = sorted(alive, key=lambda k: (seen[k].mean(), k))
            if part == 1 or not halves:  # the end of a round: the better half goes on
                alive = alive[: max(1, len(alive) // 2)]
            alive = [k for k in alive if not clearly_worse(seen[k], seen[alive[0]], margin)]
            if hopeless is not None and hopeless(seen[alive[0]], blocks):
                return RaceResult(plans[alive[0]], spent, True, seen[alive[0]], blocks)
            if len(alive) == 1:
                break
        budget *= 2
    return RaceResult(plans[alive[0]], spent, False, seen[alive[0]], blocks)


def clearly_worse(e_l: np.ndarray, leader: np.ndarray, margin: float) -> bool:
    """Whether per-sample ``e_l`` is above ``leader``'s (the same samples) by more than ``margin`` standard errors
    of the paired difference (a one-sided paired test; never with fewer than 2 samples)."""
    diff = e_l - leader
    if len(diff) < 2:
        return False
    return bool(diff.mean() > margin * diff.std(ddof=1) / np.sqrt(len(diff)))


def fresh_blocks(samples: int, fresh: int, looks: int = 1) -> list[tuple[int, int]]:
    """(samples, Monte Carlo seed) of each block of a fresh set of ``samples`` seen in ``looks`` looks.

    Look j (0-based) has seen ``samples`` / 2^(looks - 1 - j) samples in all (fewer looks when
    ``samples`` is too small to halve); block 0 is drawn from ``fresh``, block b from a seed derived
    from (``fresh``, b). With one look: the one set of ``samples`` drawn from ``fresh``.
    """
    looks = max(1, min(looks, samples.bit_length()))
    seen = [max(1, samples >> (looks - 1 - j)) for j in range(looks)]
    sizes = [seen[0]] + [b - a for a, b in zip(seen, seen[1:], strict=False)]
    return [(m, fresh if b == 0 else int(np.random.default_rng([fresh, b]).integers(2**63))) for b, m in enumerate(sizes)]


def final_check(champion: Plan, seed: Plan, evaluate: SampleEvaluator, samples: int, fresh: int,
                margin: float = MARGIN, looks: int = 1,
                hopeless: Callable[[np.ndarray, int], bool] | None = None) -> tuple[Plan, float, float, int]:
    """(kept plan, its e_l, the seed's e_l, blocks seen) on the fresh set of ``samples`` drawn from ``fresh``.

    The champion is kept only if its mean e_l is below the seed's by more than ``margin``
    standard errors of the per-sample difference (common random numbers pair the samples).
    With ``looks`` > 1 the blocks of ``fresh_blocks`` are evaluated one after the other and the
    check stops early once the difference is beyond ``EARLY_MARGIN`` standard errors either way, or, undecided, once
    ``hopeless`` (the better plan's e_l per sample, the blocks seen) says neither plan can win: then the seed is kept.
    """
    blocks = fresh_blocks(samples, fresh, looks)
    if champion.key() == seed.key():
        e_seed = float(evaluate([seed], *blocks[0])[0].mean())
        return seed, e_seed, e_seed, 1
    each = np.zeros((2, 0))
    for b, (count, block_seed) in enumerate(blocks):
        each = np.concatenate([each, evaluate([champion, seed], count, block_seed)], axis=1)
        diff, last = each[0] - each[1], b == len(blocks) - 1
        if len(diff) > 1:
            se = float(diff.std(ddof=1) / np.sqrt(len(diff)))
        else:  # one sample: no spread; undecided at an interim look
            se = 0.0 if last else np.inf
        z = margin if last else EARLY_MARGIN
        if diff.mean() + z * se < 0:
            return champion, float(each[0].mean()), float(each[1].mean()), b + 1
        if last or diff.mean() - z * se > 0:
            break
        if hopeless is not None and hopeless(each[int(diff.mean() > 0)], b + 1):
            break
    e_seed = float(each[1].mean())
    return seed, e_seed, e_seed, b + 1  # blocks is never empty


def best_distinct(cache: dict[PlanKey, float], count: int) -> list[Plan]:
    """The ``count`` plans with the lowest finite e_l in a ``Plan.key()`` -> e_l cache."""
    ranked = sorted((e, key) for key, e in cache.items() if np.isfinite(e))[:count]
    return [Plan(np.concatenate([np.asarray(g, dtype=np.int64) for g in key]), tuple(len(g) for g in key)) for _, key in ranked]
