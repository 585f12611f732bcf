"""Is the reported uncertainty honest? Position NEES along trajectories (``swarm study consistency``).

Every (noise setting, localizer, method) runs the same random trajectories (``inchworm.seeding``) in the
in-process simulator; after each configuration the position NEES / 2
(``coordinator.consistency``) is averaged over robots and trajectories and plotted per
configuration with its chi-square band. Near 1: the covariances match the errors; above:
overconfident; below: pessimistic. Noise settings: the model's motion sigmas (turn, drive) times each
of ``motion_scales`` and its sensing sigmas (range, bearing) times each of ``sensing_scales``
(``inchworm.noise.scaled``, as ``swarm study noise``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from coordinator.localization.registry import BUILTIN_LOCALIZERS
from inchworm.limits import check_option_limits
from inchworm.noise import scaled
from inchworm.options import check_among, check_at_least, check_localizers, check_numbers, default_selection, options_dict
from inchworm.runner import Executor, Row, StudyLog, run_tasks
from inchworm.seeding import paired_trajectory, run_seed
from runtime.models.config import ModelConfig
from runtime.models.trajectory import body_spacing
from runtime.paths import StrPath

if TYPE_CHECKING:
    from matplotlib.axes import Axes

    from coordinator.selection.selector import SelectionConfig

METHODS = ("no-anchors", "ref57", "heuristic-fixed", "one-at-a-time")  # fixed plans; add inchworm with methods


@dataclass(frozen=True, kw_only=True)
class ConsistencyOptions:
    """Every (noise setting, localizer, method) on the same ``trajectories`` random trajectories of ``robots`` robots and
    ``configs`` configurations; a noise setting is ``model`` with its motion sigmas times a motion scale and its
    sensing sigmas times a sensing scale."""

    localizers: tuple[str, ...] = field(default=BUILTIN_LOCALIZERS, metadata={"help": "comma-separated, any registered localizer"})
    methods: tuple[str, ...] = field(default=METHODS, metadata={"help": "comma-separated anchor methods"})
    robots: int = field(default=10, metadata={"help": "n_r"})
    configs: int = field(default=100, metadata={"help": "configurations per trajectory"})
    trajectories: int = field(default=48, metadata={
        "help": "random trajectories (default %(default)s: with 16 a consistent filter leaves [0.7, 1.5] at some configuration quite often)"})
    seed: int = field(default=0, metadata={"help": "seed of the trajectories and the noise"})
    model: ModelConfig = field(default_factory=ModelConfig)
    selection: SelectionConfig = field(default_factory=default_selection)
    motion_scales: tuple[float, ...] = field(default=(1.0,), metadata={"help": "factors on the turn and drive sigmas, one noise setting each"})
    sensing_scales: tuple[float, ...] = field(default=(1.0,), metadata={
        "help": "factors on the range and bearing sigmas, crossed with --motion-scales"})

    def __post_init__(self) -> None:
        from coordinator.strategies import METHODS  # noqa: PLC0415

        check_localizers(self)
        check_among(self, "methods", METHODS)
        check_at_least(self, "robots", 2)
        check_at_least(self, "configs", 1)
        check_at_least(self, "trajectories", 1)
        check_numbers(self, "motion_scales")
        check_numbers(self, "sensing_scales")
        check_option_limits(self)

    def settings(self) -> list[tuple[float, float]]:
        """(motion scale, sensing scale) of every noise setting."""
        return [(ms, ss) for ms in self.motion_scales for ss in self.sensing_scales]

    def tasks(self) -> list[NeesTask]:
        return [NeesTask(loc, m, t, self, ms, ss) for ms, ss in self.settings() for loc in self.localizers for m in self.methods
                for t in range(self.trajectories)]


@dataclass(frozen=True)
class NeesTask:
    localizer: str
    method: str
    t: int
    options: ConsistencyOptions
    motion_scale: float = 1.0
    sensing_scale: float = 1.0

    @property
    def key(self) -> str:
        noise = "" if (self.motion_scale, self.sensing_scale) == (1.0, 1.0) else f"m{self.motion_scale:g}/s{self.sensing_scale:g}/"
        return f"{noise}{self.localizer}/{self.method}/{self.t}"

    @property
    def model(self) -> ModelConfig:
        return scaled(self.options.model, self.motion_scale, self.sensing_scale)


def run_task(task: NeesTask) -> Row:
    """NEES / 2 after every configuration of one run (columns ``config_1`` ...)."""
    from coordinator.consistency import run_nees  # noqa: PLC0415
    from coordinator.simulate import simulate  # noqa: PLC0415

    o, model = task.options, task.model
    traj = paired_trajectory(o.robots, o.configs, o.seed, task.t, model.sensing_range_m, **body_spacing(model))
    nees = run_nees(simulate(traj, task.method, model, localizer=task.localizer, selection=o.selection, seed=run_seed(o.seed, task.t)))
    return {"localizer": task.localizer, "method": task.method, "trajectory": task.t, "motion_scale": task.motion_scale,
            "sensing_scale": task.sensing_scale, **{f"config_{c + 1}": float(v) for c, v in enumerate(nees)}}


def _json_number(x: float) -> float | None:
    """``x`` rounded to 4 significant digits; None for inf/NaN (JSON has no infinity)."""
    return float(f"{x:.4g}") if math.isfinite(x) else None


@dataclass(frozen=True)
class ConsistencyRow:
    """NEES / 2 per configuration (mean over trajectories) of one localizer and method at one noise setting."""

    localizer: str
    method: str
    per_config: np.ndarray  # (K,) mean over trajectories
    per_run: np.ndarray  # (T, K)
    motion_scale: float = 1.0
    sensing_scale: float = 1.0

    def summary(self) -> dict[str, Any]:
        """Median, 95th percentile (linear interpolation), max and min over the configurations."""
        return {
            "localizer": self.localizer,
            "method": self.method,
            "configs": int(len(self.per_config)),
            "nees_over_expected_median": _json_number(float(np.median(self.per_config))),
            "nees_over_expected_max": _json_number(float(np.max(self.per_config))),
            "nees_over_expected_min": _json_number(float(np.min(self.per_config))),
            "nees_over_expected_p95": _json_number(float(np.percentile(self.per_config, 95))),
            "motion_scale": self.motion_scale,
            "sensing_scale": self.sensing_scale,
        }


@dataclass
class ConsistencyResult:
    """One ``ConsistencyRow`` per (localizer, method) and the chi-square band of their means."""

    options: ConsistencyOptions
    rows: list[ConsistencyRow]
    band: tuple[float, float]

    def to_json(self) -> dict[str, Any]:
        return {"rows": [r.summary() for r in self.rows]}

    def report(self) -> str:
        o, (lo, hi) = self.options, self.band
        lines = [f"position NEES / 2 per configuration, mean over {o.trajectories} trajectories of {o.robots} robots"
                 f" (chi-square 95 % band {lo:.2f}-{hi:.2f} if errors were independent; target 0.7-1.5)",
                 f"{'motion':>6} {'sensing':>7} {'localizer':<9} {'method':<16} {'configs':>7} {'median':>8} {'p95':>8} {'max':>8} {'min':>8}"]

        def fmt(x: float | None) -> str:
            return "inf" if x is None else f"{x:.3g}"

        for s in self.to_json()["rows"]:
            lines.append(f"{s['motion_scale']:>6g} {s['sensing_scale']:>7g} {s['localizer']:<9} {s['method']:<16} {s['configs']:>7} "
                         f"{fmt(s['nees_over_expected_median']):>8} {fmt(s['nees_over_expected_p95']):>8} "
                         f"{fmt(s['nees_over_expected_max']):>8} {fmt(s['nees_over_expected_min']):>8}")
        return "\n".join(lines)

    def plot(self, ax: Axes, localizer: str | None = None) -> Axes:
        """NEES / 2 per configuration of every method (and noise setting, when there are several) of ``localizer``
        (log scale), with the chi-square band and the target."""
        from matplotlib.ticker import MaxNLocator  # noqa: PLC0415

        from inchworm.plots import title  # noqa: PLC0415

        loc = localizer or self.options.localizers[0]
        k = 0
        for r in self.rows:
            if r.localizer == loc:
                k = len(r.per_config)
                noise = "" if len(self.options.settings()) == 1 else f" (motion x{r.motion_scale:g}, sensing x{r.sensing_scale:g})"
                ax.plot(np.arange(1, k + 1), np.clip(r.per_config, 1e-3, 1e6), label=r.method + noise)
        ax.axhspan(*self.band, color="0.85", label="chi-square 95 % band")
        ax.axhline(1.0, color="k", lw=0.8, label="consistent (1)")
        ax.axhspan(0.7, 1.5, fill=False, ls="--", ec="tab:green", label="target 0.7-1.5")
        ax.set_yscale("log")
        ax.set_xlabel("configuration")
        ax.set_ylabel("position NEES / 2 (mean over robots and trajectories)")
        ax.set_xlim(1, max(k, 2))
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.legend(fontsize=8)
        title(ax, f"{loc} localizer")
        return ax

    def save(self, out: StrPath) -> list[Path]:
        """``consistency.png``: one panel per localizer."""
        out = Path(out)
        from inchworm.plots import save_figure  # noqa: PLC0415

        locs = self.options.localizers

        def draw(axes: Any) -> None:
            for ax, loc in zip(np.ravel(axes), locs, strict=False):
                self.plot(ax, loc)

        return [save_figure(draw, out / "consistency.png", (6.5 * len(locs), 4.8), (1, len(locs)), squeeze=False, sharey=True)]


def study_consistency(
    options: ConsistencyOptions | None = None,
    *,
    executor: Executor | None = None,
    out: StrPath | None = None,
    resume: bool = False,
    progress: Callable[[int, int], None] | None = None,
) -> ConsistencyResult:
    """NEES / 2 of every (localizer, method); with ``out`` every run is kept in ``out/runs.jsonl`` and ``out/runs.csv`` as it finishes."""
    options = ConsistencyOptions() if options is None else options
    from coordinator.consistency import chi2_band  # noqa: PLC0415

    log = StudyLog(out, "runs", options_dict(options), resume) if out is not None else None
    runs = run_tasks(run_task, options.tasks(), executor=executor, log=log, progress=progress)
    if log is not None:
        log.finish(runs)
    rows = []
    for ms, ss in options.settings():
        for loc in options.localizers:
            for m in options.methods:
                per_run = np.array([[r[f"config_{c + 1}"] for c in range(options.configs)] for r in runs
                                    if (r["localizer"], r["method"], r.get("motion_scale", 1.0), r.get("sensing_scale", 1.0)) == (loc, m, ms, ss)])
                rows.append(ConsistencyRow(loc, m, per_run.mean(axis=0), per_run, ms, ss))
    return ConsistencyResult(options, rows, chi2_band(options.robots, options.trajectories))
