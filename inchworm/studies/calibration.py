"""At which noise does ref57's P_f match the paper's Table I, and what then? (``swarm study calibration``)

The paper states no noise levels. For each localizer and sensing-noise scale, the motion
noise scale (turn and drive sigmas together) at which ref57's mean P_f (Eq. 24) equals
``target`` (the paper's 0.0673) is found by bisection on log(scale) over
``calibration_trajectories`` random trajectories (their own seeds, not used again).
There the methods run on every seed set of ``seeds`` (``trajectories`` each, paired:
every method on the same trajectories and noise streams); per seed set and pooled, the
P_f ratio against ref57 and the paired t-test p-value. P_f falls with trajectory length
(the final error grows more slowly than the distance travelled), so the calibrated noise
holds for ``configs`` configurations, not for the paper's 100.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from coordinator.localization.registry import BUILTIN_LOCALIZERS
from coordinator.strategies import METHODS
from inchworm.comparison import REFERENCE, RunTask, run_one, summarise
from inchworm.limits import check_option_limits
from inchworm.noise import scaled
from inchworm.options import RunOptions, check_among, check_at_least, check_localizers, check_numbers, options_dict
from inchworm.runner import Executor, Row, StudyLog, run_tasks
from runtime.errors import OptionError
from runtime.models.config import ModelConfig
from runtime.paths import StrPath

PAPER_REF57_PF = 0.0673  # Table I, ref. [57]
CALIBRATION_SEED = 10**6  # calibration trajectories use seeds CALIBRATION_SEED + t


@dataclass(frozen=True, kw_only=True)
class CalibrationOptions:
    """The calibration (``target``, bisection budget) and the comparison run at the calibrated noise."""

    localizers: tuple[str, ...] = field(default=BUILTIN_LOCALIZERS, metadata={"help": "localizers, any registered one"})
    sensing_scales: tuple[float, ...] = field(default=(1.0,), metadata={"help": "factors on range and bearing sigmas"})
    target: float = field(default=PAPER_REF57_PF, metadata={"help": "ref57 P_f to match (default the paper's %(default)s)"})
    max_motion_scale: float = field(default=32.0, metadata={"help": "largest factor on turn and drive sigmas tried"})
    calibration_trajectories: int = field(default=12, metadata={"help": "ref57 trajectories per bisection step"})
    iterations: int = field(default=7, metadata={"help": "bisection steps on log(motion scale)"})
    robots: int = field(default=10, metadata={"help": "robots per trajectory"})
    trajectories: int = field(default=30, metadata={"help": "trajectories per seed set"})
    configs: int = field(default=15, metadata={"help": "configurations per trajectory"})
    seeds: tuple[int, ...] = field(default=(0, 1000), metadata={"help": "seed sets; trajectory t of set s uses seed s + t"})
    methods: tuple[str, ...] = field(default=("inchworm", "inchworm-equal-speed", "ref57"), metadata={
        "help": "comma-separated methods compared with ref57 at the calibrated noise"})
    run: RunOptions = field(default_factory=RunOptions)

    def __post_init__(self) -> None:
        check_among(self, "methods", METHODS)
        check_localizers(self)
        if REFERENCE not in self.methods:
            raise OptionError("methods", f"must include {REFERENCE} (the ratios are against it)", self)
        for name in ("trajectories", "configs", "calibration_trajectories", "iterations"):
            check_at_least(self, name, 1)
        if not self.target > 0:
            raise OptionError("target", f"must be > 0, got {self.target}", self)
        if not self.max_motion_scale > 1:
            raise OptionError("max_motion_scale", f"must be > 1, got {self.max_motion_scale}", self)
        check_numbers(self, "seeds")
        check_numbers(self, "sensing_scales")
        check_at_least(self, "robots", 2)
        check_option_limits(self)


@dataclass
class _Runs:
    """Runs of the study through one executor and log; calibration runs are kept in the log but not in the CSV."""

    executor: Executor | None
    log: StudyLog | None
    progress: Callable[[int, int], None] | None = None
    done: int = 0
    total: int = 0

    def calibration(self, tasks: list[RunTask]) -> list[Row]:
        return run_tasks(run_one, tasks, executor=self.executor, log=self.log, csv=False)

    def comparison(self, tasks: list[RunTask]) -> list[Row]:
        start = self.done

        def tick(done: int, _total: int) -> None:
            self.done = start + done
            if self.progress is not None:
                self.progress(self.done, self.total)

        return run_tasks(run_one, tasks, executor=self.executor, log=self.log, progress=tick)


def calibrate(options: CalibrationOptions, localizer: str, sensing: float, runs: _Runs) -> tuple[float, float]:
    """(motion scale, ref57 mean P_f there): bisection on log(scale) in [1, max_motion_scale]."""
    o = options

    def pf(motion: float) -> float:
        tags = (("phase", "calibration"), ("localizer", localizer), ("sensing_scale", sensing), ("motion_scale", motion))
        tasks = [RunTask(t, REFERENCE, o.robots, o.configs, CALIBRATION_SEED, scaled(o.run.model, motion, sensing), localizer,
                         o.run.selection, tags=tags) for t in range(o.calibration_trajectories)]
        return float(np.mean([r["pf"] for r in runs.calibration(tasks)]))

    lo, hi = 0.0, math.log(o.max_motion_scale)
    for _ in range(o.iterations):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if pf(math.exp(mid)) < o.target else (lo, mid)
    motion = math.exp(0.5 * (lo + hi))
    return motion, pf(motion)


def compare_at(options: CalibrationOptions, cfg: ModelConfig, localizer: str, sensing: float, motion: float,
               runs: _Runs) -> tuple[dict[str, Any], list[Row]]:
    """Per seed set and pooled: P_f per method, ratio to ref57 and paired p-values."""
    o = options
    tags = (("localizer", localizer), ("sensing_scale", sensing), ("motion_scale", motion))
    tasks = [RunTask(t, m, o.robots, o.configs, s, cfg, localizer, o.run.selection, tags=(*tags, ("seed_set", s)))
             for s in o.seeds for t in range(o.trajectories) for m in o.methods]
    rows = runs.comparison(tasks)
    out: dict[str, Any] = {}
    methods = list(o.methods)
    for label, subset in [(str(s), [r for r in rows if r["seed_set"] == s]) for s in o.seeds] + [("pooled", rows)]:
        keyed = [{**r, "trajectory": (r["seed_set"], r["trajectory"])} for r in subset]
        summary = summarise(keyed, methods)
        ref = summary["methods"][REFERENCE]["pf_mean"]
        out[label] = {
            "pf": {m: summary["methods"][m]["pf_mean"] for m in methods},
            "na": {m: summary["methods"][m]["na_mean"] for m in methods},
            "na_by_config": {m: summary["methods"][m]["na_by_config"] for m in methods},  # mean n_a at configuration 1, 2, ...
            "drift_pct": {m: summary["methods"][m]["drift_pct_mean"] for m in methods},  # final e_l / distance travelled x 100
            "over_ref57": {m: summary["methods"][m]["pf_mean"] / ref for m in methods if m != REFERENCE},
            "contacts_per_100": {m: summary["methods"][m]["contacts_per_100"] for m in methods},
            "p_values": summary["p_values"],
            "trajectories": len(subset) // len(methods),
        }
    return out, rows


@dataclass
class CalibrationResult:
    """The runs at the calibrated noise (``rows``) and per (localizer, sensing scale) the calibration and comparison (``results``)."""

    options: CalibrationOptions
    rows: list[Row]
    results: list[dict[str, Any]]

    def to_json(self) -> dict[str, Any]:
        o = self.options
        return {"results": self.results, "seeds": list(o.seeds), "trajectories": o.trajectories, "configs": o.configs, "target": o.target}

    def report(self) -> str:
        o = self.options
        others = [m for m in o.methods if m != REFERENCE]
        lines = [f"{r['localizer']}, sensing x {r['sensing_scale']:g}: ref57 P_f = {r['ref57_pf_calibration']:.4f} at motion noise x "
                 f"{r['motion_scale']:.2f} (calibration set)" for r in self.results]
        lines.append(f"{'localizer':<9} {'sensing x':>9} {'motion x':>8} {'seeds':>8} {'ref57 P_f':>10} "
                     + " ".join(f"{m + ' / ref57':>28} {'p':>6}" for m in others))
        for r in self.results:
            for label in [str(s) for s in o.seeds] + ["pooled"]:
                s = r[label]
                cells = " ".join(f"{s['over_ref57'][m]:>28.3f} {s['p_values'].get(m, float('nan')):>6.3f}" for m in others)
                lines.append(f"{r['localizer']:<9} {r['sensing_scale']:>9g} {r['motion_scale']:>8.2f} {label:>8} {s['pf'][REFERENCE]:>10.4f} {cells}")
        for r in self.results:
            for m in o.methods:
                along = " ".join(f"{v:.1f}" for v in r["pooled"]["na_by_config"][m])
                lines.append(f"{r['localizer']}, sensing x {r['sensing_scale']:g}, {m}: drift {r['pooled']['drift_pct'][m]:.2f} %, "
                             f"n_a along the trajectory {along}")
        lines.append(f"({o.trajectories} trajectories x {o.configs} configurations per seed set, n_r = {o.robots})")
        return "\n".join(lines)

    def plot(self, ax: Any) -> Any:
        """Pooled P_f of every method at each calibrated setting (bars: 97 % t-interval of the mean, clipped at 0)."""
        from inchworm.plots import title  # noqa: PLC0415
        from inchworm.stats import CONFIDENCE, clipped_at_zero, mean_ci  # noqa: PLC0415

        o = self.options
        width = 0.8 / len(o.methods)
        for k, m in enumerate(o.methods):
            means, lows, highs = [], [], []
            for r in self.results:
                pf = np.array([x["pf"] for x in self.rows
                               if x["method"] == m and x["localizer"] == r["localizer"] and x["sensing_scale"] == r["sensing_scale"]])
                lo, hi = clipped_at_zero(*mean_ci(pf, CONFIDENCE))
                means.append(pf.mean())
                lows.append(pf.mean() - lo)
                highs.append(hi - pf.mean())
            x = np.arange(len(self.results)) + (k - (len(o.methods) - 1) / 2) * width
            ax.bar(x, means, width, yerr=np.nan_to_num([lows, highs]), capsize=3, label=m)
        ax.set_xticks(range(len(self.results)),
                      [f"{r['localizer']}, sensing x {r['sensing_scale']:g}\nmotion x {r['motion_scale']:.2f}" for r in self.results])
        ax.axhline(o.target, color="black", ls="--", lw=0.8, label=f"target ref57 P_f {o.target:g}")
        ax.set_ylim(bottom=0)
        ax.set_ylabel("P_f (Eq. 24)")
        ax.legend(fontsize=8)
        title(ax, "P_f at the calibrated noise (bars: 97 % CI of the mean, t, clipped at 0)")
        return ax

    def save(self, out: StrPath) -> list[Path]:
        """``calibration.png``: the pooled P_f of every method at each calibrated setting."""
        from inchworm.plots import save_figure  # noqa: PLC0415

        out = Path(out)
        return [save_figure(self.plot, out / "calibration.png", (max(6.0, 2.5 * len(self.results) + 3), 4.5))]


def study_calibration(
    options: CalibrationOptions | None = None,
    *,
    executor: Executor | None = None,
    out: StrPath | None = None,
    resume: bool = False,
    progress: Callable[[int, int], None] | None = None,
) -> CalibrationResult:
    """Calibrate, then compare at the calibrated noise; with ``out`` every run is kept in ``out/runs.jsonl`` (calibration runs too)
    and the comparison runs in ``out/runs.csv`` as they finish."""
    options = CalibrationOptions() if options is None else options
    o = options
    log = StudyLog(out, "runs", options_dict(options), resume) if out is not None else None
    runs = _Runs(executor, log, progress, total=len(o.localizers) * len(o.sensing_scales) * len(o.seeds) * o.trajectories * len(o.methods))
    results, all_rows = [], []
    for loc in o.localizers:
        for ss in o.sensing_scales:
            motion, pf_cal = calibrate(o, loc, ss, runs)
            stats, rows = compare_at(o, scaled(o.run.model, motion, ss), loc, ss, motion, runs)
            all_rows += rows
            results.append({"localizer": loc, "sensing_scale": ss, "motion_scale": motion, "ref57_pf_calibration": pf_cal, **stats})
    if log is not None:
        log.finish(all_rows)
    return CalibrationResult(options, all_rows, results)
