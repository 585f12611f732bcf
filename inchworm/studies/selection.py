"""The online anchor search against the true optimum, by exhaustive enumeration (``swarm study selection``).

Every configuration is one random step of ``study anchors`` (random connected start,
desired configuration 0.1-0.6 m away, start estimate 0.01 m / 2 deg). For every anchor
count whose ordered partitions (Eq. 10) number at most ``EXHAUSTIVE_LIMIT``
(n_r = 8: n_a = 4 with 70 plans and n_a = 6 with 2520), the optimum among the plans the search may
return (connected after every step and, with bodies, every step clear: ``BodyCheck`` of the start
estimate, docs/bodies.md) is found in three independent Monte Carlo sets (common random numbers within each):

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
(Eq. 3) on the evaluation set (``na_agrees``; n_a = 0 competes only where its one step, every
robot moving, is connected and clear: ``na0_clear``, as in the search's outer loop), and the e_l it reports for its plan is
compared with that plan's e_l on the evaluation set (the bias of the reported e_l).
"""

from __future__ import annotations

import csv
import functools
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from inchworm.limits import check_option_limits
from inchworm.options import RunOptions, check_at_least, options_dict
from inchworm.runner import Executor, Row, StudyLog, run_tasks
from inchworm.studies.anchors import CHUNK, Job, experiment_setup
from runtime.errors import OptionError
from runtime.paths import StrPath

if TYPE_CHECKING:  # annotations only: the search and plotting are imported when a study runs
    from matplotlib.axes import Axes

    from coordinator.plan import Plan
    from coordinator.selection.monte_carlo import MonteCarlo
    from coordinator.selection.selector import SelectionConfig
    from runtime.models.state import SwarmEstimate


EXHAUSTIVE_LIMIT = 5000  # ordered partitions per anchor count enumerated
INT_COLUMNS = ("config", "chosen_na", "best_na", "na_agrees", "na0_clear", "no_clear_plan", "na_within_noise")
SHORTLIST = 16  # best plans of the screening set re-evaluated to pick the optimum


@dataclass(frozen=True)
class Budget:
    screen: int
    pick: int
    eval: int


def _errors(mc: MonteCarlo, estimate: SwarmEstimate, desired: np.ndarray, plans: list[Plan]) -> np.ndarray:
    return np.concatenate([mc.localization_errors(estimate, desired, plans[i : i + CHUNK]) for i in range(0, len(plans), CHUNK)])


@dataclass(frozen=True)
class ConfigTask:
    """One configuration change of the study (its seeds are those of ``job``)."""

    job: Job
    selection: SelectionConfig
    budget: Budget

    @property
    def key(self) -> str:
        return str(self.job.experiment)


def run_config(task: ConfigTask) -> Row:
    """One configuration change: the flat row of e_l (m) on the evaluation set and the ratios."""
    from coordinator.plan import Plan, enumerate_plans, feasible_anchor_counts, n_solutions, n_steps, speed_performance  # noqa: PLC0415
    from coordinator.selection.clear_pairs import PairTable  # noqa: PLC0415
    from coordinator.selection.genetic import genetic_search  # noqa: PLC0415
    from coordinator.selection.heuristic import heuristic_plan  # noqa: PLC0415
    from coordinator.selection.monte_carlo import MonteCarlo, plan_keeps_connectivity  # noqa: PLC0415
    from coordinator.selection.selector import AnchorSelector, NoFeasiblePlanError, samples_for, search_samples  # noqa: PLC0415
    from runtime.models.bodies import BodyCheck  # noqa: PLC0415
    job, selection, budget = task.job, task.selection, task.budget
    n = job.robots
    rng, start, desired, estimate, mc = experiment_setup(job)
    localizer = mc.localizer  # one object for every Monte Carlo and selector of the experiment
    current = start[:, :2]
    sets = [int(rng.integers(2**63)) for _ in range(3)]
    screen, pick, final = (MonteCarlo(job.cfg, localizer, s, seed, task.selection.mc_start)  # the selection's reading of the start
                           for s, seed in zip((budget.screen, budget.pick, budget.eval), sets, strict=True))

    pairs = PairTable(BodyCheck.of_estimate(job.cfg, estimate, desired))  # the search's collision constraint (docs/bodies.md)

    def feasible(plan: Plan) -> bool:
        return bool(pairs.clear([plan])[0]) and plan_keeps_connectivity(plan, current, desired, job.cfg.sensing_range_m)

    online = AnchorSelector(job.cfg, localizer, selection, seed=job.experiment).select(estimate, desired)
    row: Row = {"config": job.experiment, "chosen_na": online.n_anchors}
    all_move = Plan.equal(np.arange(n), 0)
    e0 = float(final.localization_errors(estimate, desired, [all_move])[0])
    # n_a = 0 (P_l = 1) competes only where its one step is a plan the search may return: with bodies it can be crowded
    row["na0_clear"] = int(feasible(all_move))
    best_p_s = {0: selection.w_v - selection.w_l} if row["na0_clear"] else {}
    best_plan = {0: all_move}  # the best clear plan known of each count (on the evaluation set)
    for n_a in (k for k in feasible_anchor_counts(n) if k > 0):
        heuristic = heuristic_plan(current, desired, n_a)
        forced = AnchorSelector(job.cfg, localizer, replace(selection, anchor_counts=(n_a,)), seed=job.experiment)
        try:
            searched = forced.select(estimate, desired).plan
        except NoFeasiblePlanError:  # no plan of this count keeps the swarm connected
            continue
        screen_samples = search_samples(samples_for(selection.samples, n), n_solutions(n, n_a))
        screen_mc = MonteCarlo(job.cfg, localizer, screen_samples, int(rng.integers(2**63)), task.selection.mc_start)
        raw, _, _ = genetic_search(functools.partial(screen_mc.localization_errors, estimate, desired), [heuristic], feasible,
                                   np.random.default_rng([job.seed, job.experiment, n_a]), selection.genetic)
        randoms = [p for p in (Plan.equal(rng.permutation(n), n_a) for _ in range(20)) if feasible(p)][:1]
        plans = {"heuristic": heuristic, "search": searched, "ga_raw": raw or heuristic}
        row[f"na{n_a}_search_clear"] = int(feasible(searched))  # 0: the search found no plan that keeps bodies apart
        if randoms:
            plans["random"] = randoms[0]
        paired = final.localization_errors(estimate, desired, [heuristic, searched], per_sample=True)
        row[f"na{n_a}_search_is_seed"] = int(searched.key() == heuristic.key())
        row[f"na{n_a}_gain_se"] = float(np.std(paired[0] - paired[1], ddof=1) / np.sqrt(paired.shape[1]))  # m
        exhaustive = job.exhaustive and n_solutions(n, n_a) <= EXHAUSTIVE_LIMIT
        if exhaustive:
            enumerated = enumerate_plans(n, n_a)
            every = [p for p, clear in zip(enumerated, pairs.clear(enumerated), strict=True)
                     if clear and plan_keeps_connectivity(p, current, desired, job.cfg.sensing_range_m)]
            row[f"na{n_a}_clear_plans"] = len(every)
        if exhaustive and every:
            shortlist = [every[k] for k in np.argsort(_errors(screen, estimate, desired, every), kind="stable")[:SHORTLIST]]
            plans["optimum"] = shortlist[int(np.argmin(_errors(pick, estimate, desired, shortlist)))]
        e = dict(zip(plans, (float(v) for v in _errors(final, estimate, desired, list(plans.values()))), strict=True))
        for name, value in e.items():
            row[f"na{n_a}_{name}"] = value
        valid = [v for name, v in e.items() if feasible(plans[name])]  # the heuristic or the search may be crowded
        if not valid:
            continue
        best = min(valid)
        best_plan[n_a] = next(plans[name] for name, v in e.items() if v == best and feasible(plans[name]))
        best_p_s[n_a] = selection.w_v * speed_performance(n, n_a) - selection.w_l * best / e0
        if online.n_anchors == n_a:
            reported = next(s.e_l for s in online.scores if s.n_anchors == n_a)
            row["reported_over_fresh"] = reported / float(_errors(final, estimate, desired, [online.plan])[0])
    row["no_clear_plan"] = int(not best_p_s)
    if best_p_s:
        row["best_na"] = max(best_p_s, key=lambda k: (best_p_s[k], -k))
    else:  # no count has a clear plan: the search's rule, the connected heuristic plan with the fewest steps
        connected = [k for k in feasible_anchor_counts(n)
                     if plan_keeps_connectivity(all_move if k == 0 else heuristic_plan(current, desired, k), current, desired,
                                                job.cfg.sensing_range_m)]
        row["best_na"] = min(connected, key=lambda k: (n_steps(n, k), k), default=-1)
    row["na_agrees"] = int(row["best_na"] == online.n_anchors)
    row["na_gap_se"] = 0.0 if row["na_agrees"] else count_gap(final, estimate, desired, selection, best_plan, row["best_na"],
                                                               online.n_anchors)
    row["na_within_noise"] = int(row["na_gap_se"] <= BEYOND_NOISE)
    return row


def count_gap(final: MonteCarlo, estimate: SwarmEstimate, desired: np.ndarray, selection: SelectionConfig, best_plan: dict[int, Plan],
              best_na: int, chosen_na: int) -> float:
    """How many standard errors the best count's P_s (Eq. 3) exceeds the chosen count's on the evaluation set: each
    count's best clear plan known, e_l per sample on the same samples (common random numbers), P_l = e_l / the mean
    e_l(0) there; inf when the chosen count has no clear plan, 0 when no count has one."""
    from coordinator.plan import Plan, speed_performance  # noqa: PLC0415
    if best_na not in best_plan:
        return 0.0
    if chosen_na not in best_plan:
        return float("inf")
    n = len(desired)
    e0 = final.localization_errors(estimate, desired, [Plan.equal(np.arange(n), 0)], per_sample=True)[0].mean()

    def p_s(n_a: int) -> np.ndarray:
        e_l = final.localization_errors(estimate, desired, [best_plan[n_a]], per_sample=True)[0]
        out: np.ndarray = selection.w_v * speed_performance(n, n_a) - selection.w_l * e_l / e0
        return out
    gap = p_s(best_na) - p_s(chosen_na)
    return float(gap.mean() / (gap.std(ddof=1) / np.sqrt(len(gap))))


def summarise(rows: list[Row], robots: int) -> dict[str, Any]:
    """Per count and pooled: ratios of e_l to the optimum on the evaluation set (m / m)."""
    from coordinator.plan import feasible_anchor_counts  # noqa: PLC0415
    out: dict[str, Any] = {"counts": {}}
    pooled: dict[str, list[float]] = {}
    for n_a in (k for k in feasible_anchor_counts(robots) if k > 0):
        with_opt = [r for r in rows if f"na{n_a}_optimum" in r]
        if not with_opt:
            continue
        entry = {}
        for name in ("search", "ga_raw", "heuristic", "random"):
            ratios = [r[f"na{n_a}_{name}"] / r[f"na{n_a}_optimum"] for r in with_opt if f"na{n_a}_{name}" in r
                      and (name != "search" or r.get(f"na{n_a}_search_clear", 1))]  # a crowded plan is no plan
            pooled.setdefault(name, []).extend(ratios)
            entry[name] = ({"median": float(np.median(ratios)), "max": float(np.max(ratios)), "mean": float(np.mean(ratios))}
                           if ratios else {"median": np.nan, "max": np.nan, "mean": np.nan})
        vs = [r[f"na{n_a}_search"] / r[f"na{n_a}_heuristic"] for r in with_opt]
        entry["search_over_heuristic"] = {"median": float(np.median(vs)) if vs else np.nan, "worse": int(sum(v > 1 for v in vs)),
                                          "cases": len(vs)}
        out["counts"][str(n_a)] = entry
    out["pooled"] = {k: {"median": float(np.median(v)), "max": float(np.max(v))} for k, v in pooled.items() if v}
    vs = [r[f"na{k}_search"] / r[f"na{k}_heuristic"] for r in rows for k in feasible_anchor_counts(robots) if f"na{k}_search" in r]
    out["search_over_heuristic_median"] = float(np.median(vs)) if vs else None
    out["search_vs_heuristic"] = search_vs_heuristic(rows, robots)
    out["search_missing"] = sum(1 for r in rows for k in feasible_anchor_counts(robots)
                                if r.get(f"na{k}_clear_plans", 0) > 0 and not r.get(f"na{k}_search_clear", 1))
    bias = [r["reported_over_fresh"] for r in rows if "reported_over_fresh" in r]
    out["reported_over_fresh_median"] = float(np.median(bias)) if bias else None
    return out


BEYOND_NOISE = 2.0  # standard errors of the paired difference on the evaluation set


def search_vs_heuristic(rows: list[Row], robots: int) -> dict[str, dict[str, int]]:
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


def within_noise(row: Row) -> int:
    """1 where the chosen count's P_s is within ``BEYOND_NOISE`` standard errors of the best count's (rows of studies
    before this column: whether they agree)."""
    return int(row["na_within_noise"] if "na_within_noise" in row else row["na_agrees"])


def read_rows(path: Path) -> list[Row]:
    """The rows of a study's ``configs.csv`` (numbers back as numbers, empty cells dropped)."""
    if not path.exists():
        raise OptionError("from_csv", f": no such file {path}")
    with open(path, newline="") as f:
        rows = [{k: (int(v) if k in INT_COLUMNS else float(v)) for k, v in r.items() if v != ""} for r in csv.DictReader(f)]
    if not rows:
        raise OptionError("from_csv", f": {path} has no rows")
    return rows


@dataclass(frozen=True, kw_only=True)
class SelectionStudyOptions:
    """``configs`` random configuration changes of ``robots`` robots; configuration c uses the seed [seed, c]."""

    robots: int = field(default=8, metadata={"help": "n_r"})
    configs: int = field(default=20, metadata={"help": "random configuration changes"})
    screen_samples: int = field(default=32, metadata={"help": "samples per plan to shortlist the exhaustive enumeration"})
    pick_samples: int = field(default=256, metadata={"help": "fresh samples to pick the optimum from the shortlist"})
    eval_samples: int = field(default=512, metadata={"help": "fresh samples every reported plan is evaluated on"})
    seed: int = field(default=0, metadata={"help": "configuration c uses the seed [seed, c]"})
    run: RunOptions = field(default_factory=RunOptions)
    optimum: bool = field(default=True, metadata={  # False: skip the exhaustive enumeration
        "help": "skip the exhaustive optimum (search against the heuristic only)", "flag": "--no-optimum"})

    def __post_init__(self) -> None:
        check_at_least(self, "robots", 3)
        check_at_least(self, "configs", 1)
        for name in ("screen_samples", "pick_samples", "eval_samples"):
            check_at_least(self, name, 1)
        check_option_limits(self)

    def budget(self) -> Budget:
        return Budget(self.screen_samples, self.pick_samples, self.eval_samples)

    def tasks(self) -> list[ConfigTask]:
        b = self.budget()
        return [ConfigTask(Job(c, self.robots, b.screen, self.seed, self.run.model, self.run.localizer, self.optimum), self.run.selection, b)
                for c in range(self.configs)]


@dataclass
class SelectionStudyResult:
    """One row per configuration change (e_l in m on the evaluation set) and the summary of the ratios to the optimum."""

    options: SelectionStudyOptions
    rows: list[Row]
    summary: dict[str, Any]

    def to_json(self) -> dict[str, Any]:
        pooled = self.summary["pooled"]
        return {
            "ga_over_optimum_median": pooled["search"]["median"] if "search" in pooled else None,
            "ga_over_optimum_max": pooled["search"]["max"] if "search" in pooled else None,
            "heuristic_over_optimum_median": pooled["heuristic"]["median"] if "heuristic" in pooled else None,
            "na_agrees": sum(r["na_agrees"] for r in self.rows),
            "configs": len(self.rows),
            "search_vs_heuristic": self.summary["search_vs_heuristic"],
            "search_missing": self.summary["search_missing"],
            "na_within_noise": sum(within_noise(r) for r in self.rows),
        }

    def report(self) -> str:
        o = self.options
        lines = [f"swarm study selection: n_r = {o.robots}, {len(self.rows)} configurations, localizer {o.run.localizer}, "
                 f"selection {o.run.selection.method}; e_l on {o.eval_samples} fresh samples / optimum's",
                 f"{'n_a':>4} {'plan':<10} {'median':>7} {'mean':>7} {'max':>7}"]
        for n_a, entry in self.summary["counts"].items():
            for name in ("search", "ga_raw", "heuristic", "random"):
                s = entry[name]
                lines.append(f"{n_a:>4} {name:<10} {s['median']:>7.4f} {s['mean']:>7.4f} {s['max']:>7.4f}")
            h = entry["search_over_heuristic"]
            lines.append(f"{n_a:>4} search / heuristic: median {h['median']:.4f}, worse in {h['worse']} of {h['cases']}")
        for n_a, v in self.summary["search_vs_heuristic"].items():
            lines.append(f"{n_a:>4} search returned its heuristic seed in {v['seed_returned']} of {v['cases']}; beat it by more than "
                         f"{BEYOND_NOISE:g} standard errors in {v['beats']}, lost by as much in {v['loses']}")
        lines.append(f"counts with a clear plan (bodies kept apart) where the search returned none: {self.summary['search_missing']}")
        agrees = sum(r["na_agrees"] for r in self.rows)
        lines.append(f"chosen n_a = best n_a on the evaluation set in {agrees} of {len(self.rows)} (chosen: {[r['chosen_na'] for r in self.rows]})")
        tied = sum(within_noise(r) for r in self.rows)
        lines.append(f"chosen n_a's P_s within {BEYOND_NOISE:g} standard errors of the best n_a's (paired, evaluation set) in {tied} of "
                     f"{len(self.rows)}; no count with a clear plan (the search's fallback compared) in "
                     f"{sum(int(r['no_clear_plan']) for r in self.rows if 'no_clear_plan' in r)}")
        if self.summary["reported_over_fresh_median"] is not None:
            lines.append(f"e_l reported by the selection / its fresh e_l: median {self.summary['reported_over_fresh_median']:.3f}")
        return "\n".join(lines)

    def plot(self, ax: Axes) -> Axes:
        """Per anchor count, the e_l of each plan kind over the optimum's (one marker per configuration; 1 = optimal)."""
        from inchworm.plots import title  # noqa: PLC0415

        kinds = ("search", "ga_raw", "heuristic", "random")
        counts = list(self.summary["counts"])
        for k, name in enumerate(kinds):
            for j, n_a in enumerate(counts):
                ratios = [r[f"na{n_a}_{name}"] / r[f"na{n_a}_optimum"] for r in self.rows if f"na{n_a}_optimum" in r and f"na{n_a}_{name}" in r]
                ax.scatter(np.full(len(ratios), j + (k - 1.5) * 0.18), ratios, s=14, color=f"C{k}", label=name if j == 0 else None)
        ax.axhline(1.0, color="black", lw=0.8, label="optimum")
        ax.set_xticks(range(len(counts)), [f"n_a = {c}" for c in counts])
        ax.set_ylabel("e_l / e_l of the optimum")
        ax.legend(fontsize=8)
        title(ax, f"Anchor plans against the exhaustive optimum, n_r = {self.options.robots}")
        return ax

    def save(self, out: StrPath) -> list[Path]:
        """``selection.png``: the plans against the optimum (when an anchor count was enumerated)."""
        from inchworm.plots import save_figure  # noqa: PLC0415

        out = Path(out)
        return [save_figure(self.plot, out / "selection.png", (7.0, 4.5))] if self.summary["counts"] else []


def study_selection(
    options: SelectionStudyOptions | None = None,
    *,
    executor: Executor | None = None,
    out: StrPath | None = None,
    resume: bool = False,
    progress: Callable[[int, int], None] | None = None,
) -> SelectionStudyResult:
    """Run the study; with ``out`` every configuration is kept in ``out/configs.jsonl`` and ``out/configs.csv`` as it finishes."""
    options = SelectionStudyOptions() if options is None else options
    log = StudyLog(out, "configs", options_dict(options), resume) if out is not None else None
    rows = run_tasks(run_config, options.tasks(), executor=executor, log=log, progress=progress)
    if log is not None:
        log.finish(rows)
    return SelectionStudyResult(options, rows, summarise(rows, options.robots))


def selection_from_csv(path: Path, options: SelectionStudyOptions) -> SelectionStudyResult:
    """The result of the rows of an earlier (possibly interrupted) study's ``configs.csv``."""
    rows = read_rows(path)
    return SelectionStudyResult(options, rows, summarise(rows, options.robots))
