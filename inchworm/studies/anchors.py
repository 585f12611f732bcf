"""The paper's anchor studies (``swarm study anchors``), Fig. 4, Fig. 5 (Section 4.1) and Fig. A1 (Appendix A).

Every experiment moves a swarm of n_r robots from a random connected start (random
headings) to a random desired configuration (one step of ``random_trajectory``, moved by
a distance drawn from 0.1-0.6 m so the figures span a range of distances), always
from the same uncertain start estimate (position std 0.01 m, heading std 2 deg). All
plans of an experiment are evaluated by one ``MonteCarlo`` estimator, i.e. on common
random numbers (same initial-estimate error, motion noise and sensing noise draws), so
their e_l (Eq. 8) differ only because of the plan.

1. Fig. 4, number of anchors: a random plan for every feasible n_a (Eq. 7) -> e_l, and
   e_l(n_a) / e_l(0).
2. Fig. 5, choice of anchors (n_r even, n_a = n_r / 2): every ordered 2-group plan
   (C(n_r, n_r/2) of them; 252 for n_r = 10) -> e_l with no anchors, random, worst and
   best anchors. Skipped when there are more than ``EXHAUSTIVE_LIMIT`` plans.
3. Appendix A: the heuristic plan (Eq. 11-13) against the random plan at the same n_a,
   and the heuristic's percentile among all plans when part 2 ran.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from inchworm.limits import check_option_limits
from inchworm.options import check_at_least, check_localizers, options_dict
from inchworm.runner import Executor, Row, StudyLog, run_tasks
from inchworm.seeding import trajectory_rng
from runtime.models.config import ModelConfig
from runtime.models.state import SwarmEstimate
from runtime.models.trajectory import body_spacing, random_trajectory
from runtime.paths import StrPath

if TYPE_CHECKING:  # annotations only: the search and plotting are imported when a study runs
    from matplotlib.axes import Axes

    from coordinator.plan import Plan
    from coordinator.selection.monte_carlo import MonteCarlo


EXHAUSTIVE_LIMIT = 5000  # plans per experiment for part 2 (Fig. 5)
CHUNK = 1024  # plans per MonteCarlo call (memory bound; common random numbers make chunks comparable)
START_DELTA_M = 0.01  # position std of the uncertain start estimate (m)
STEP_RANGE_M = (0.1, 0.6)  # rigid move of the desired configuration, drawn per experiment
START_HEADING_DEG = 2.0  # heading std of the uncertain start estimate
CHOICES = ("none", "random", "worst", "best")


# ---------------------------------------------------------------------------- experiments


@dataclass(frozen=True)
class Job:
    """One experiment; picklable so worker processes can run it."""

    experiment: int
    robots: int
    samples: int
    seed: int
    cfg: ModelConfig
    localizer: str
    exhaustive: bool = True  # False: skip part 2 (Fig. 5) even when it applies

    @property
    def key(self) -> str:
        return str(self.experiment)


def choice_anchor_count(n: int) -> int:
    """n_a of parts 2 and 3: n_r / 2, or for odd n_r the feasible n_a > 0 nearest to it."""
    from coordinator.plan import feasible_anchor_counts  # noqa: PLC0415
    if n % 2 == 0:
        return n // 2
    return min((k for k in feasible_anchor_counts(n) if k > 0), key=lambda k: (abs(k - n / 2), k))


def exhaustive_count(n: int) -> int:
    """Number of ordered 2-group plans with n_a = n_r / 2 (0 when n_r is odd: part 2 does not apply)."""
    return math.comb(n, n // 2) if n % 2 == 0 else 0


def exhaustive_plans(n: int) -> list[Plan]:
    """Every plan with n_a = n_r / 2: first mobile group from ``combinations``, the second its complement."""
    from coordinator.plan import Plan  # noqa: PLC0415
    everyone = set(range(n))
    return [Plan.equal(np.array([*first, *sorted(everyone - set(first))]), n // 2) for first in itertools.combinations(range(n), n // 2)]


def evaluate(mc: MonteCarlo, estimate: SwarmEstimate, desired: np.ndarray, plans: list[Plan]) -> np.ndarray:
    """e_l per plan, ``CHUNK`` plans per call (same step count required)."""
    return np.concatenate([mc.localization_errors(estimate, desired, plans[i : i + CHUNK]) for i in range(0, len(plans), CHUNK)])


def experiment_setup(job: Job) -> tuple[np.random.Generator, np.ndarray, np.ndarray, SwarmEstimate, MonteCarlo]:
    """The random start (n, 3), desired configuration (n, 2), start estimate and e_l estimator of an experiment."""
    from coordinator.localization import make_localizer  # noqa: PLC0415
    from coordinator.selection.monte_carlo import MonteCarlo  # noqa: PLC0415
    rng = trajectory_rng(job.seed, job.experiment)  # the study's seeding convention (inchworm.seeding)
    step = rng.uniform(*STEP_RANGE_M)  # spread the distance travelled, the x-axis of Fig. 4/5/A1
    traj = random_trajectory(job.robots, 1, rng, sensing_range=job.cfg.sensing_range_m, step=step, **body_spacing(job.cfg))
    start, desired = traj.initial_poses, traj.configurations[0]
    estimate = SwarmEstimate.isotropic(traj.ids, start, START_DELTA_M, math.radians(START_HEADING_DEG))
    mc = MonteCarlo(job.cfg, make_localizer(job.localizer, job.cfg), job.samples, int(rng.integers(2**63)))
    return rng, start, desired, estimate, mc


def run_experiment(job: Job) -> Row:
    """All three parts for one experiment: a flat row (e_l in m; NaN where a part does not apply).

    When part 2 runs, the random and heuristic plans' e_l are read from the exhaustive
    evaluation (common random numbers make them identical to a separate evaluation).
    The ``*_fresh`` columns re-evaluate the plans of Fig. 5 and Appendix A with new
    random numbers (an independent Monte Carlo seed): the best and worst of many noisy
    estimates are biased (selection on noise), the fresh values are not.
    """
    from coordinator.plan import Plan, feasible_anchor_counts  # noqa: PLC0415
    from coordinator.selection.heuristic import heuristic_plan  # noqa: PLC0415
    from coordinator.selection.monte_carlo import MonteCarlo, plan_keeps_connectivity  # noqa: PLC0415
    n = job.robots
    rng, start, desired, estimate, mc = experiment_setup(job)
    counts = feasible_anchor_counts(n)
    random_plans = {n_a: Plan.equal(rng.permutation(n), n_a) for n_a in counts}
    fresh = MonteCarlo(job.cfg, mc.localizer, job.samples, int(rng.integers(2**63)))
    n_a_choice = choice_anchor_count(n)
    heuristic = heuristic_plan(start[:, :2], desired, n_a_choice)
    exhaustive = job.exhaustive and 0 < exhaustive_count(n) <= EXHAUSTIVE_LIMIT
    nan = float("nan")

    e_l: dict[int, float] = {}
    if exhaustive:
        plans = exhaustive_plans(n)
        errors = evaluate(mc, estimate, desired, plans)
        index = {p.key(): k for k, p in enumerate(plans)}
        e_random, e_heuristic = (float(errors[index[p.key()]]) for p in (random_plans[n_a_choice], heuristic))
        e_l[n_a_choice] = e_random
    for n_a in counts:
        if n_a not in e_l:
            e_l[n_a] = float(evaluate(mc, estimate, desired, [random_plans[n_a]])[0])
    if not exhaustive:
        e_random = e_l[n_a_choice]
        e_heuristic = float(evaluate(mc, estimate, desired, [heuristic])[0])
    again = [random_plans[n_a_choice], heuristic]
    if exhaustive:
        best, worst = plans[int(np.argmin(errors))], plans[int(np.argmax(errors))]
        again += [worst, best]
    fresh_none = float(evaluate(fresh, estimate, desired, [random_plans[0]])[0])
    fresh_random, fresh_heuristic, *fresh_worst_best = (float(v) for v in evaluate(fresh, estimate, desired, again))

    row: Row = {"experiment": job.experiment, "distance_m": float(np.mean(np.linalg.norm(desired - start[:, :2], axis=1)))}
    for n_a in counts:
        row[f"e_l_na{n_a}"] = e_l[n_a]
    for n_a in counts:
        row[f"ratio_na{n_a}"] = e_l[n_a] / e_l[0] if e_l[0] > 0 else nan
    row["choice_n_anchors"] = n_a_choice
    row["choice_plans"] = len(plans) if exhaustive else 0
    row["choice_plans_connected"] = (
        sum(plan_keeps_connectivity(p, start[:, :2], desired, job.cfg.sensing_range_m) for p in plans) if exhaustive else 0
    )
    row["choice_none"] = e_l[0] if exhaustive else nan
    row["choice_random"] = e_random if exhaustive else nan
    row["choice_worst"] = float(errors.max()) if exhaustive else nan
    row["choice_best"] = float(errors.min()) if exhaustive else nan
    row["choice_none_fresh"] = fresh_none if exhaustive else nan
    row["choice_random_fresh"] = fresh_random if exhaustive else nan
    row["choice_worst_fresh"] = fresh_worst_best[0] if exhaustive else nan
    row["choice_best_fresh"] = fresh_worst_best[1] if exhaustive else nan
    row["best_first_movers"] = " ".join(map(str, best.groups[0].tolist())) if exhaustive else ""
    row["heuristic_e_l"] = e_heuristic
    row["heuristic_random_e_l"] = e_random
    row["heuristic_beats_random"] = int(e_heuristic < e_random)
    row["heuristic_e_l_fresh"] = fresh_heuristic
    row["heuristic_random_e_l_fresh"] = fresh_random
    row["heuristic_connected"] = int(plan_keeps_connectivity(heuristic, start[:, :2], desired, job.cfg.sensing_range_m))
    # percentile 0 = best plan of the experiment, 100 = worst; a random plan averages about 50
    row["heuristic_percentile"] = percentile(errors, e_heuristic) if exhaustive else nan
    row["random_percentile"] = percentile(errors, e_random) if exhaustive else nan
    return row


def percentile(errors: np.ndarray, value: float) -> float:
    """Share (%) of the other plans that are strictly better than ``value`` (0 = best, 100 = worst)."""
    return 100.0 * float(np.sum(errors < value)) / max(len(errors) - 1, 1)


# ---------------------------------------------------------------------------- summary


def _mean(values: list[float]) -> float | None:
    v = np.asarray(values, float)
    v = v[np.isfinite(v)]
    return float(v.mean()) if len(v) else None


def summarise(rows: list[Row], robots: int) -> dict[str, Any]:
    """The JSON contract (e_l in m): per-n_a means and ratios, Fig. 5 means, heuristic vs random."""
    from coordinator.plan import feasible_anchor_counts  # noqa: PLC0415
    counts = feasible_anchor_counts(robots)
    e_mean = {str(k): _mean([r[f"e_l_na{k}"] for r in rows]) for k in counts}
    out: dict[str, Any] = {
        "robots": robots,
        "experiments": len(rows),
        "distance_mean": _mean([r["distance_m"] for r in rows]),
        "e_l_mean": e_mean,
        "e_l_ratio": {str(k): _mean([r[f"ratio_na{k}"] for r in rows]) for k in counts},  # mean of per-experiment ratios
        "e_l_ratio_of_means": {str(k): (mk / m0 if (mk := e_mean[str(k)]) is not None and (m0 := e_mean["0"]) else None) for k in counts},
        "choice_n_anchors": choice_anchor_count(robots),
        "choice": None,
    }
    exhaustive = [r for r in rows if r["choice_plans"] > 0]
    if exhaustive:
        out["choice"] = {c: _mean([r[f"choice_{c}"] for r in exhaustive]) for c in CHOICES}
        out["choice_fresh"] = {c: _mean([r[f"choice_{c}_fresh"] for r in exhaustive]) for c in CHOICES}
        out["choice_plans"] = exhaustive[0]["choice_plans"]
    out["heuristic"] = {
        "n_anchors": choice_anchor_count(robots),
        "e_l_mean": _mean([r["heuristic_e_l"] for r in rows]),
        "random_e_l_mean": _mean([r["heuristic_random_e_l"] for r in rows]),
        "e_l_mean_fresh": _mean([r["heuristic_e_l_fresh"] for r in rows]),
        "random_e_l_mean_fresh": _mean([r["heuristic_random_e_l_fresh"] for r in rows]),
        "beats_random_fraction": _mean([r["heuristic_beats_random"] for r in rows]),
        "percentile_mean": _mean([r["heuristic_percentile"] for r in exhaustive]) if exhaustive else None,
        "random_percentile_mean": _mean([r["random_percentile"] for r in exhaustive]) if exhaustive else None,
        "connected_fraction": _mean([r["heuristic_connected"] for r in rows]),
    }
    return out


def _std_mm(values: list[float]) -> float:
    v = np.asarray(values, float)
    return float(v.std(ddof=1)) * 1000 if len(v) > 1 else 0.0


def report(rows: list[Row], summary: dict[str, Any], samples: int, localizer: str) -> str:
    """The human-readable tables (e_l in mm)."""
    from coordinator.plan import feasible_anchor_counts, n_steps  # noqa: PLC0415
    n, counts = summary["robots"], feasible_anchor_counts(summary["robots"])
    dist = np.array([r["distance_m"] for r in rows])

    def mm(v: float | None) -> str:
        return "-" if v is None else f"{1000 * v:.2f}"

    lines = [
        f"swarm study anchors: n_r = {n}, {len(rows)} experiments, {samples} Monte Carlo samples per plan, localizer {localizer}",
        f"average distance travelled: mean {dist.mean():.3f} m (min {dist.min():.3f}, max {dist.max():.3f})",
        "",
        "Fig. 4 - number of anchors (one random plan per n_a and experiment)",
        f"{'n_a':>4} {'n_s':>4} {'P_v':>5} {'e_l mean (mm)':>14} {'std (mm)':>9} {'e_l/e_l(0) mean':>16} {'ratio of means':>15}",
    ]
    for k in counts:
        lines.append(
            f"{k:>4} {n_steps(n, k):>4} {1 / n_steps(n, k):>5.2f} {mm(summary['e_l_mean'][str(k)]):>14} "
            f"{_std_mm([r[f'e_l_na{k}'] for r in rows]):>9.2f} {summary['e_l_ratio'][str(k)]:>16.3f} {summary['e_l_ratio_of_means'][str(k)]:>15.3f}"
        )
    lines.append("")
    n_a = summary["choice_n_anchors"]
    if summary["choice"] is None:
        why = f"n_r = {n} is odd" if n % 2 else f"{exhaustive_count(n)} plans per experiment > {EXHAUSTIVE_LIMIT}"
        lines.append(f"Fig. 5 - choice of anchors: skipped ({why})")
    else:
        exhaustive = [r for r in rows if r["choice_plans"] > 0]
        connected = np.mean([r["choice_plans_connected"] / r["choice_plans"] for r in exhaustive])
        lines.append(f"Fig. 5 - choice of anchors, n_a = {n_a}: all {summary['choice_plans']} plans per experiment "
                     f"({100 * connected:.0f} % keep the swarm connected, Eq. 4)")
        lines.append(f"{'anchors':<8} {'e_l mean (mm)':>14} {'std (mm)':>9} {'/ none':>7} {'fresh draws (mm)':>17} {'/ none':>7}")
        none, none_fresh = summary["choice"]["none"], summary["choice_fresh"]["none"]
        for c in CHOICES:
            v, f = summary["choice"][c], summary["choice_fresh"][c]
            lines.append(f"{c:<8} {mm(v):>14} {_std_mm([r[f'choice_{c}'] for r in exhaustive]):>9.2f} {v / none:>7.3f} "
                         f"{mm(f):>17} {f / none_fresh:>7.3f}")
        lines.append("(fresh draws: the same plans re-evaluated with independent random numbers; best/worst of 252 noisy estimates are biased)")
    lines.append("")
    h = summary["heuristic"]
    wins = sum(r["heuristic_beats_random"] for r in rows)
    lines.append(f"Appendix A - heuristic (Eq. 11-13) vs random anchors, n_a = {n_a}")
    lines.append(f"{'anchors':<10} {'e_l mean (mm)':>14} {'std (mm)':>9} {'fresh draws (mm)':>17}")
    lines.append(f"{'heuristic':<10} {mm(h['e_l_mean']):>14} {_std_mm([r['heuristic_e_l'] for r in rows]):>9.2f} {mm(h['e_l_mean_fresh']):>17}")
    lines.append(f"{'random':<10} {mm(h['random_e_l_mean']):>14} {_std_mm([r['heuristic_random_e_l'] for r in rows]):>9.2f} "
                 f"{mm(h['random_e_l_mean_fresh']):>17}")
    diff = np.array([r["heuristic_e_l"] - r["heuristic_random_e_l"] for r in rows])
    se = _std_mm(list(diff)) / math.sqrt(len(diff))
    lines.append(
        f"heuristic - random (paired): mean {1000 * diff.mean():+.3f} mm (standard error {se:.3f}, "
        f"{100 * diff.mean() / h['random_e_l_mean']:+.1f} %); heuristic better in {wins}/{len(rows)} experiments ({100 * wins / len(rows):.0f} %)"
    )
    if h["percentile_mean"] is not None:
        lines.append(f"percentile among all plans (0 = best, 100 = worst): heuristic {h['percentile_mean']:.1f}, "
                     f"random {h['random_percentile_mean']:.1f}")
    lines.append(f"heuristic plans keeping the swarm connected (Eq. 4): {100 * h['connected_fraction']:.0f} %")
    return "\n".join(lines)


# ---------------------------------------------------------------------------- plots


def scatter_panels(axes: Any, panels: list[tuple[str, np.ndarray]], distance: np.ndarray) -> None:
    """One panel per (title, e_l (m) per experiment): e_l (mm) against the average distance travelled (m), from 0."""
    from inchworm.plots import title  # noqa: PLC0415

    flat = list(np.ravel(axes))
    for ax, (label, values) in zip(flat, panels, strict=False):
        ok = np.isfinite(values)
        ax.scatter(distance[ok], 1000 * values[ok], s=10, alpha=0.7, label="one experiment")
        if ok.any():
            ax.axhline(1000 * values[ok].mean(), color="tab:red", lw=1, ls="--", label=f"mean {1000 * values[ok].mean():.2f} mm")
        ax.legend(loc="upper left", fontsize=8)
        ax.set_xlim(left=0)
        ax.set_ylim(bottom=0)
        ax.grid(alpha=0.3)
        ax.set_xlabel("average distance travelled (m)")
        ax.set_ylabel("localization error e_l (mm)")
        title(ax, label, 10)
    for ax in flat[len(panels):]:
        ax.set_visible(False)


def _save_panels(panels: list[tuple[str, np.ndarray]], distance: np.ndarray, heading: str, path: Path) -> Path:
    from inchworm.plots import save_figure  # noqa: PLC0415

    k = len(panels)
    cols = 2 if k == 4 else k
    rows = math.ceil(k / cols)

    def draw(axes: Any) -> None:
        scatter_panels(axes, panels, distance)
        axes[0, 0].get_figure().suptitle(heading)

    return save_figure(draw, path, (4.2 * cols, 3.6 * rows + 0.4), (rows, cols), squeeze=False, sharex=True, sharey=True)


# ---------------------------------------------------------------------------- the study


@dataclass(frozen=True, kw_only=True)
class AnchorsOptions:
    """``experiments`` random experiments of ``robots`` robots, ``samples`` Monte Carlo samples per plan; experiment e uses the seed [seed, e]."""

    robots: int = field(default=10, metadata={"help": "n_r"})
    experiments: int = field(default=60, metadata={"help": "random experiments (default %(default)s; the paper: 1000)"})
    samples: int = field(default=8, metadata={"help": "Monte Carlo samples per plan per experiment"})
    seed: int = field(default=0, metadata={"help": "experiment e uses the seed [seed, e]"})
    model: ModelConfig = field(default_factory=ModelConfig)
    localizer: str = "paper"

    def __post_init__(self) -> None:
        check_at_least(self, "robots", 3)
        check_at_least(self, "experiments", 1)
        check_at_least(self, "samples", 1)
        check_localizers(self, "localizer")
        check_option_limits(self)

    def note(self) -> str | None:
        """Why Fig. 5 is skipped, if it is."""
        n = self.robots
        if n % 2 == 0 and exhaustive_count(n) > EXHAUSTIVE_LIMIT:
            return f"note: Fig. 5 skipped: n_r = {n} has {exhaustive_count(n)} plans with n_a = {n // 2} per experiment (> {EXHAUSTIVE_LIMIT})"
        if n % 2:
            return f"note: Fig. 5 skipped: n_a = n_r / 2 is not feasible for odd n_r = {n}; Appendix A uses n_a = {choice_anchor_count(n)}"
        return None

    def tasks(self) -> list[Job]:
        return [Job(e, self.robots, self.samples, self.seed, self.model, self.localizer) for e in range(self.experiments)]


@dataclass
class AnchorsResult:
    """One row per experiment (e_l in m) and the summary (the ``swarm study anchors --json`` object)."""

    options: AnchorsOptions
    rows: list[Row]
    summary: dict[str, Any]

    def to_json(self) -> dict[str, Any]:
        return self.summary

    def report(self) -> str:
        return report(self.rows, self.summary, self.options.samples, self.options.localizer)

    def _col(self, key: str) -> np.ndarray:
        return np.array([r[key] for r in self.rows], float)

    def panels(self) -> dict[str, list[tuple[str, np.ndarray]]]:
        """The panels (title, e_l per experiment) of Fig. 4, Fig. 5 (when part 2 ran) and Fig. A1."""
        from coordinator.plan import feasible_anchor_counts  # noqa: PLC0415

        letters = "abcdefghijklmnopqrstuvwxyz"
        out = {"fig4": [(f"({letters[i % 26]}) {k} anchors", self._col(f"e_l_na{k}"))
                        for i, k in enumerate(feasible_anchor_counts(self.options.robots))]}
        if self.summary["choice"] is not None:
            names = {"none": "zero anchors", "random": "random anchors", "worst": "global worst anchors", "best": "global best anchors"}
            out["fig5"] = [(f"({letters[i]}) {names[c]}", self._col(f"choice_{c}")) for i, c in enumerate(CHOICES)]
        out["appendix_a"] = [("(a) anchors from the heuristic", self._col("heuristic_e_l")),
                             ("(b) random anchors", self._col("heuristic_random_e_l"))]
        return out

    def plot(self, ax: Axes) -> Axes:
        """Appendix A on one axes: e_l of the heuristic and of the random anchors against the distance travelled."""
        from inchworm.plots import title  # noqa: PLC0415

        distance = self._col("distance_m")
        for label, values, marker in (("heuristic anchors", self._col("heuristic_e_l"), "o"),
                                      ("random anchors", self._col("heuristic_random_e_l"), "^")):
            ax.scatter(distance, 1000 * values, s=12, marker=marker, alpha=0.7, label=label)
        ax.set_xlim(left=0)
        ax.set_ylim(bottom=0)
        ax.set_xlabel("average distance travelled (m)")
        ax.set_ylabel("localization error e_l (mm)")
        ax.legend(fontsize=8)
        title(ax, f"Heuristic vs random anchors, n_a = {self.summary['choice_n_anchors']} of n_r = {self.options.robots}")
        return ax

    def save(self, out: StrPath) -> list[Path]:
        """fig4.png, fig5.png (when part 2 ran) and appendix_a.png in ``out`` (experiments.csv is written as experiments finish)."""
        out = Path(out)
        n, n_a, k = self.options.robots, self.summary["choice_n_anchors"], len(self.rows)
        headings = {"fig4": f"Fig. 4: e_l vs number of anchors, n_r = {n}, {k} experiments",
                    "fig5": f"Fig. 5: choice of anchors, n_a = {n_a} of n_r = {n}",
                    "appendix_a": f"Fig. A1: heuristic vs random anchors, n_a = {n_a} of n_r = {n}"}
        distance = self._col("distance_m")
        return [_save_panels(panels, distance, headings[name], out / f"{name}.png") for name, panels in self.panels().items()]


def study_anchors(
    options: AnchorsOptions | None = None,
    *,
    executor: Executor | None = None,
    out: StrPath | None = None,
    resume: bool = False,
    progress: Callable[[int, int], None] | None = None,
) -> AnchorsResult:
    """Fig. 4, Fig. 5 and Appendix A; with ``out`` each experiment is kept in ``out/experiments.jsonl`` and ``.csv`` as it finishes."""
    options = AnchorsOptions() if options is None else options
    log = StudyLog(out, "experiments", options_dict(options), resume) if out is not None else None
    rows = run_tasks(run_experiment, options.tasks(), executor=executor, log=log, progress=progress)
    if log is not None:
        log.finish(rows)
    return AnchorsResult(options, rows, summarise(rows, options.robots))
