"""``swarm study selection``: the online anchor search against the true optimum (exhaustive enumeration).

Every configuration is one random step of ``study anchors`` (random connected start,
desired configuration 0.1-0.6 m away, start estimate 0.01 m / 2 deg). For every anchor
count whose ordered partitions (Eq. 10) number at most ``EXHAUSTIVE_LIMIT``
(n_r = 8: n_a = 4 with 70 plans and n_a = 6 with 2520), the optimum is found in three
independent Monte Carlo sets (common random numbers within each):

1. every plan on ``--screen-samples`` samples -> the ``SHORTLIST`` best,
2. the shortlist on ``--pick-samples`` fresh samples -> the optimum,
3. the optimum, the heuristic plan (Eq. 11-13), the plan of the online search
   (``AnchorSelector`` restricted to that n_a: genetic search, race, final check), the
   raw genetic search (its best plan by its own samples alone, ``search_samples`` of
   them, the search before the race and final check) and a random connected plan, all on ``--eval-samples``
   fresh samples: the ratios to the optimum come from this set only, so no ratio is
   biased by a choice made on the same draws.

The full online selection (every feasible n_a, as ``swarm sim`` runs it) is also run;
its chosen n_a is compared with the n_a whose best known plan has the highest P_s
(Eq. 3) on the evaluation set (``na_agrees``), and the e_l it reports for its plan is
compared with that plan's e_l on the evaluation set (the bias of the reported e_l).
"""

from __future__ import annotations

import argparse
import csv
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path

from typing import TYPE_CHECKING

import numpy as np

from runtime.models.config import ModelConfig
from runtime.errors import SwarmInputError
from swarm_cli.options import add_simulation_options, add_workers_option, model_config, print_json, selection_config
from swarm_cli.progress import Progress
from swarm_cli.study_anchors import CHUNK, Job, experiment_setup

if TYPE_CHECKING:  # annotations only: the search and plotting are imported when a command runs
    from coordinator.plan import Plan
    from coordinator.selection.monte_carlo import MonteCarlo
    from coordinator.selection.selector import SelectionConfig


EXHAUSTIVE_LIMIT = 5000  # ordered partitions per anchor count enumerated
INT_COLUMNS = ("config", "chosen_na", "best_na", "na_agrees")
SHORTLIST = 16  # best plans of the screening set re-evaluated to pick the optimum


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("selection", help="online anchor search vs exhaustive optimum, heuristic and random plans")
    p.add_argument("--robots", type=int, default=8, help="n_r (default 8)")
    p.add_argument("--configs", type=int, default=20, help="random configuration changes (default 20)")
    p.add_argument("--screen-samples", type=int, default=32, help="samples per plan to shortlist the exhaustive enumeration (default 32)")
    p.add_argument("--pick-samples", type=int, default=256, help="fresh samples to pick the optimum from the shortlist (default 256)")
    p.add_argument("--eval-samples", type=int, default=512, help="fresh samples every reported plan is evaluated on (default 512)")
    p.add_argument("--seed", type=int, default=0, help="configuration c uses the seed [seed, c] (default 0)")
    add_workers_option(p)
    p.add_argument("--out", type=Path, default=Path("out/study-selection"), help="folder for configs.csv")
    p.add_argument("--no-optimum", action="store_true", help="skip the exhaustive optimum (search against the heuristic only)")
    p.add_argument("--from-csv", type=Path, default=None, help="summarise the rows of an earlier (possibly interrupted) study's configs.csv instead of running")
    add_simulation_options(p)
    p.set_defaults(run=run)


@dataclass(frozen=True)
class Budget:
    screen: int
    pick: int
    eval: int


def _errors(mc: MonteCarlo, estimate, desired, plans: list[Plan]) -> np.ndarray:
    return np.concatenate([mc.localization_errors(estimate, desired, plans[i : i + CHUNK]) for i in range(0, len(plans), CHUNK)])


def run_config(args: tuple[Job, SelectionConfig, Budget]) -> dict:
    """One configuration change: the flat row of e_l (m) on the evaluation set and the ratios."""
    from coordinator.plan import Plan, enumerate_plans, feasible_anchor_counts, n_solutions, speed_performance  # noqa: PLC0415
    from coordinator.selection.genetic import genetic_search  # noqa: PLC0415
    from coordinator.selection.heuristic import heuristic_plan  # noqa: PLC0415
    from coordinator.selection.monte_carlo import MonteCarlo, plan_keeps_connectivity  # noqa: PLC0415
    from coordinator.selection.selector import AnchorSelector, NoFeasiblePlanError, samples_for, search_samples  # noqa: PLC0415
    job, selection, budget = args
    n = job.robots
    rng, start, desired, estimate, _ = experiment_setup(job)
    current = start[:, :2]
    sets = [int(rng.integers(2**63)) for _ in range(3)]
    screen, pick, final = (MonteCarlo(job.cfg, job.localizer, s, seed, selection.mc_start)  # the selection's reading of the start
                           for s, seed in zip((budget.screen, budget.pick, budget.eval), sets))

    def feasible(plan: Plan) -> bool:
        return plan_keeps_connectivity(plan, current, desired, job.cfg.sensing_range_m)

    online = AnchorSelector(job.cfg, job.localizer, selection, seed=job.experiment).select(estimate, desired)
    row: dict = {"config": job.experiment, "chosen_na": online.n_anchors}
    all_move = Plan.equal(np.arange(n), 0)
    e0 = float(final.localization_errors(estimate, desired, [all_move])[0])
    best_p_s = {0: selection.w_v - selection.w_l}
    for n_a in (k for k in feasible_anchor_counts(n) if k > 0):
        heuristic = heuristic_plan(current, desired, n_a)
        forced = AnchorSelector(job.cfg, job.localizer, replace(selection, anchor_counts=(n_a,)), seed=job.experiment)
        try:
            searched = forced.select(estimate, desired).plan
        except NoFeasiblePlanError:  # no plan of this count keeps the swarm connected
            continue
        screen_samples = search_samples(samples_for(selection.samples, n), n_solutions(n, n_a))
        screen_mc = MonteCarlo(job.cfg, job.localizer, screen_samples, int(rng.integers(2**63)), selection.mc_start)
        raw, _, _ = genetic_search(lambda ps: screen_mc.localization_errors(estimate, desired, ps), [heuristic], feasible,
                                   np.random.default_rng([job.seed, job.experiment, n_a]), selection.genetic)
        randoms = [p for p in (Plan.equal(rng.permutation(n), n_a) for _ in range(20)) if feasible(p)][:1]
        plans = {"heuristic": heuristic, "search": searched, "ga_raw": raw or heuristic}
        if randoms:
            plans["random"] = randoms[0]
        paired = final.localization_errors(estimate, desired, [heuristic, searched], per_sample=True)
        row[f"na{n_a}_search_is_seed"] = int(searched.key() == heuristic.key())
        row[f"na{n_a}_gain_se"] = float(np.std(paired[0] - paired[1], ddof=1) / np.sqrt(paired.shape[1]))  # m
        exhaustive = job.exhaustive and n_solutions(n, n_a) <= EXHAUSTIVE_LIMIT
        if exhaustive:
            every = [p for p in enumerate_plans(n, n_a) if feasible(p)]
            shortlist = [every[k] for k in np.argsort(_errors(screen, estimate, desired, every), kind="stable")[:SHORTLIST]]
            plans["optimum"] = shortlist[int(np.argmin(_errors(pick, estimate, desired, shortlist)))]
        e = dict(zip(plans, (float(v) for v in _errors(final, estimate, desired, list(plans.values())))))
        for name, value in e.items():
            row[f"na{n_a}_{name}"] = value
        best = min(e.values())
        best_p_s[n_a] = selection.w_v * speed_performance(n, n_a) - selection.w_l * best / e0
        if online.n_anchors == n_a:
            reported = next(s.e_l for s in online.scores if s.n_anchors == n_a)
            row["reported_over_fresh"] = reported / float(_errors(final, estimate, desired, [online.plan])[0])
    row["best_na"] = max(best_p_s, key=lambda k: (best_p_s[k], -k))
    row["na_agrees"] = int(row["best_na"] == online.n_anchors)
    return row


def summarise(rows: list[dict], robots: int) -> dict:
    """Per count and pooled: ratios of e_l to the optimum on the evaluation set (m / m)."""
    from coordinator.plan import feasible_anchor_counts  # noqa: PLC0415
    out: dict = {"counts": {}}
    pooled: dict[str, list[float]] = {}
    for n_a in (k for k in feasible_anchor_counts(robots) if k > 0):
        with_opt = [r for r in rows if f"na{n_a}_optimum" in r]
        if not with_opt:
            continue
        entry = {}
        for name in ("search", "ga_raw", "heuristic", "random"):
            ratios = [r[f"na{n_a}_{name}"] / r[f"na{n_a}_optimum"] for r in with_opt if f"na{n_a}_{name}" in r]
            pooled.setdefault(name, []).extend(ratios)
            entry[name] = {"median": float(np.median(ratios)), "max": float(np.max(ratios)), "mean": float(np.mean(ratios))}
        vs = [r[f"na{n_a}_search"] / r[f"na{n_a}_heuristic"] for r in with_opt]
        entry["search_over_heuristic"] = {"median": float(np.median(vs)), "worse": int(sum(v > 1 for v in vs)), "cases": len(vs)}
        out["counts"][str(n_a)] = entry
    out["pooled"] = {k: {"median": float(np.median(v)), "max": float(np.max(v))} for k, v in pooled.items() if v}
    vs = [r[f"na{k}_search"] / r[f"na{k}_heuristic"] for r in rows for k in feasible_anchor_counts(robots) if f"na{k}_search" in r]
    out["search_over_heuristic_median"] = float(np.median(vs)) if vs else None
    out["search_vs_heuristic"] = search_vs_heuristic(rows, robots)
    bias = [r["reported_over_fresh"] for r in rows if "reported_over_fresh" in r]
    out["reported_over_fresh_median"] = float(np.median(bias)) if bias else None
    return out


BEYOND_NOISE = 2.0  # standard errors of the paired difference on the evaluation set


def search_vs_heuristic(rows: list[dict], robots: int) -> dict[str, dict[str, int]]:
    """Per count: selections, how many returned the heuristic seed, and how many beat it (or lost to it) on the
    evaluation set by more than ``BEYOND_NOISE`` standard errors of the paired Monte Carlo difference."""
    from coordinator.plan import feasible_anchor_counts  # noqa: PLC0415
    out = {}
    for n_a in (k for k in feasible_anchor_counts(robots) if k > 0):
        have = [r for r in rows if f"na{n_a}_gain_se" in r]
        if not have:
            continue
        gain = [(r[f"na{n_a}_heuristic"] - r[f"na{n_a}_search"], BEYOND_NOISE * r[f"na{n_a}_gain_se"]) for r in have]
        out[str(n_a)] = {"cases": len(have), "seed_returned": int(sum(r[f"na{n_a}_search_is_seed"] for r in have)),
                         "beats": sum(g > noise for g, noise in gain), "loses": sum(-g > noise for g, noise in gain)}
    return out


def write_rows(path: Path, rows: list[dict]) -> Path:
    """``rows`` as CSV; counts without a feasible plan leave their columns empty."""
    from swarm_cli.summary import write_csv  # noqa: PLC0415
    keys = list(dict.fromkeys(k for r in rows for k in r))
    return write_csv(path, [{k: r.get(k, "") for k in keys} for r in rows])


def read_rows(path: Path) -> list[dict]:
    """The rows ``write_rows`` wrote (numbers back as numbers, empty cells dropped)."""
    if not path.exists():
        raise SwarmInputError(f"--from-csv: no such file {path}")
    with open(path, newline="") as f:
        rows = [{k: (int(v) if k in INT_COLUMNS else float(v)) for k, v in r.items() if v != ""} for r in csv.DictReader(f)]
    if not rows:
        raise SwarmInputError(f"--from-csv: {path} has no rows")
    return rows


def run(args: argparse.Namespace) -> int:
    if args.robots < 3 or args.configs < 1 or args.workers < 1:
        raise SwarmInputError("--robots must be >= 3, --configs and --workers >= 1")
    if min(args.screen_samples, args.pick_samples, args.eval_samples) < 1:
        raise SwarmInputError("--screen-samples, --pick-samples and --eval-samples must be >= 1")
    cfg: ModelConfig = model_config(args)
    selection = selection_config(args)
    budget = Budget(args.screen_samples, args.pick_samples, args.eval_samples)
    if args.from_csv is not None:
        rows = read_rows(args.from_csv)
    else:
        jobs = [(Job(c, args.robots, budget.screen, args.seed, cfg, args.localizer, not args.no_optimum), selection, budget)
                for c in range(args.configs)]
        progress = Progress(len(jobs), "study selection")
        rows = []
        with ProcessPoolExecutor(max_workers=min(args.workers, len(jobs))) as pool:
            for row in pool.map(run_config, jobs):
                rows.append(row)
                progress(len(rows))
                write_rows(args.out / "configs.csv", rows)  # what is done survives an interrupted study
    summary = summarise(rows, args.robots)
    print(f"swarm study selection: n_r = {args.robots}, {len(rows)} configurations, localizer {args.localizer}, "
          f"selection {selection.method}; e_l on {budget.eval} fresh samples / optimum's")
    print(f"{'n_a':>4} {'plan':<10} {'median':>7} {'mean':>7} {'max':>7}")
    for n_a, entry in summary["counts"].items():
        for name in ("search", "ga_raw", "heuristic", "random"):
            s = entry[name]
            print(f"{n_a:>4} {name:<10} {s['median']:>7.4f} {s['mean']:>7.4f} {s['max']:>7.4f}")
        h = entry["search_over_heuristic"]
        print(f"{n_a:>4} search / heuristic: median {h['median']:.4f}, worse in {h['worse']} of {h['cases']}")
    for n_a, v in summary["search_vs_heuristic"].items():
        print(f"{n_a:>4} search returned its heuristic seed in {v['seed_returned']} of {v['cases']}; beat it by more than "
              f"{BEYOND_NOISE:g} standard errors in {v['beats']}, lost by as much in {v['loses']}")
    agrees = sum(r["na_agrees"] for r in rows)
    print(f"chosen n_a = best n_a on the evaluation set in {agrees} of {len(rows)} (chosen: {[r['chosen_na'] for r in rows]})")
    if summary["reported_over_fresh_median"] is not None:
        print(f"e_l reported by the selection / its fresh e_l: median {summary['reported_over_fresh_median']:.3f}")
    if args.from_csv is None:
        print(f"wrote {write_rows(args.out / 'configs.csv', rows)}")
    if args.json:
        pooled = summary["pooled"]
        print_json({
            "ga_over_optimum_median": pooled["search"]["median"] if "search" in pooled else None,
            "ga_over_optimum_max": pooled["search"]["max"] if "search" in pooled else None,
            "heuristic_over_optimum_median": pooled["heuristic"]["median"] if "heuristic" in pooled else None,
            "na_agrees": agrees,
            "configs": len(rows),
            "search_vs_heuristic": summary["search_vs_heuristic"],
        })
    return 0
