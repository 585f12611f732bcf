"""Where does the online selection choose anchors, and where does it beat ref57? (``swarm study noise``)

Sweeps the motion noise (turn and drive sigmas scaled together), the sensing noise
(range and bearing sigmas scaled together) and the localizer. For every setting the
same random trajectories are run by ``inchworm`` and ``ref57`` (and
``inchworm-equal-speed``), recording the mean anchor count the online selection chose
and the P_f ratio against ref57. Heat maps per localizer show both.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from coordinator.localization.registry import BUILTIN_LOCALIZERS
from inchworm.comparison import RunTask, anchors_along, contact_stats, run_one
from inchworm.limits import check_option_limits
from inchworm.noise import scaled
from inchworm.options import RunOptions, check_at_least, check_localizers, check_numbers, options_dict
from inchworm.runner import Executor, Row, StudyLog, run_tasks
from runtime.paths import StrPath

if TYPE_CHECKING:
    from matplotlib.axes import Axes

METHODS = ("inchworm", "inchworm-equal-speed", "ref57")


@dataclass(frozen=True, kw_only=True)
class NoiseOptions:
    """The sweep: factors on the motion and sensing sigmas of ``run.model``, localizers, and the trajectories of every setting."""

    motion_scales: tuple[float, ...] = field(default=(0.5, 1.0, 2.0, 4.0), metadata={"help": "factors on turn and drive sigmas"})
    sensing_scales: tuple[float, ...] = field(default=(0.25, 1.0, 4.0), metadata={"help": "factors on range and bearing sigmas"})
    localizers: tuple[str, ...] = field(default=BUILTIN_LOCALIZERS, metadata={"help": "localizers to sweep, any registered one"})
    robots: int = field(default=10, metadata={"help": "robots per trajectory"})
    trajectories: int = field(default=3, metadata={"help": "random trajectories per setting"})
    configs: int = field(default=4, metadata={"help": "configurations per trajectory"})
    seed: int = field(default=0, metadata={"help": "seed of the trajectories and noise"})
    run: RunOptions = field(default_factory=RunOptions)

    def __post_init__(self) -> None:
        check_localizers(self)
        check_numbers(self, "motion_scales")
        check_numbers(self, "sensing_scales")
        check_at_least(self, "robots", 2)
        check_at_least(self, "trajectories", 1)
        check_at_least(self, "configs", 1)
        check_option_limits(self)

    def settings(self) -> list[tuple[str, float, float]]:
        return [(loc, ms, ss) for loc in self.localizers for ms in self.motion_scales for ss in self.sensing_scales]

    def tasks(self) -> list[RunTask]:
        base, sel = self.run.model, self.run.selection
        return [RunTask(t, m, self.robots, self.configs, self.seed, scaled(base, ms, ss), loc, sel,
                        tags=(("localizer", loc), ("motion_scale", ms), ("sensing_scale", ss)))
                for loc, ms, ss in self.settings() for t in range(self.trajectories) for m in METHODS]


@dataclass
class NoiseResult:
    """Every run (``rows``) and per setting the chosen n_a and the P_f ratios (``results``)."""

    options: NoiseOptions
    rows: list[Row]
    results: list[dict[str, Any]]

    def to_json(self) -> dict[str, Any]:
        o = self.options
        return {"results": self.results, "trajectories": o.trajectories, "configs": o.configs, "robots": o.robots}

    def report(self) -> str:
        lines = [f"{'localizer':<9} {'motion x':>8} {'sensing x':>9} {'n_a chosen':>10} {'P_f inchworm/ref57':>19} {'equal-speed/ref57':>18}"]
        lines += [f"{r['localizer']:<9} {r['motion_scale']:>8g} {r['sensing_scale']:>9g} {r['inchworm_na_mean']:>10.2f} "
                  f"{r['inchworm_over_ref57']:>19.3f} {r['equal_speed_over_ref57']:>18.3f}" for r in self.results]
        for r in self.results:
            drift = ", ".join(f"{m} {v:.2f}" for m, v in r["drift_pct"].items())
            lines.append(f"{r['localizer']} motion x {r['motion_scale']:g} sensing x {r['sensing_scale']:g}: inchworm n_a along the "
                         f"trajectory {' '.join(f'{v:.1f}' for v in r['inchworm_na_by_config'])}; drift % {drift}")
        return "\n".join(lines)

    def grid(self, localizer: str, key: str) -> np.ndarray:
        """``key`` of every setting of ``localizer``: rows motion scales, columns sensing scales."""
        o = self.options
        return np.array([[next(r[key] for r in self.results if r["localizer"] == localizer and r["motion_scale"] == m and r["sensing_scale"] == s)
                          for s in o.sensing_scales] for m in o.motion_scales])

    def plot(self, ax: Axes, localizer: str | None = None, key: str = "inchworm_over_ref57") -> Axes:
        """Heat map of ``key`` (the P_f ratio inchworm / ref57, or ``inchworm_na_mean``) over the noise scales of ``localizer``."""
        from inchworm.plots import title  # noqa: PLC0415

        o = self.options
        loc = localizer or o.localizers[0]
        grid = self.grid(loc, key)
        ratio = key == "inchworm_over_ref57"
        im = ax.imshow(grid, cmap="RdBu_r" if ratio else "viridis", origin="lower", aspect="auto",
                       vmin=0.5 if ratio else None, vmax=1.5 if ratio else None)
        for (i, j), v in np.ndenumerate(grid):
            ax.text(j, i, f"{v:.2f}", ha="center", va="center", color="black" if ratio else "white")
        ax.set_xticks(range(len(o.sensing_scales)), [f"{s:g}" for s in o.sensing_scales])
        ax.set_yticks(range(len(o.motion_scales)), [f"{m:g}" for m in o.motion_scales])
        ax.set_xlabel("sensing noise scale")
        ax.set_ylabel("motion noise scale")
        ax.figure.colorbar(im, ax=ax)
        title(ax, f"{loc}: " + ("P_f inchworm / ref57 (< 1: inchworm better)" if ratio else "n_a chosen by inchworm"))
        return ax

    def save(self, out: StrPath) -> list[Path]:
        """``noise.png``: per localizer the chosen n_a and the P_f ratio."""
        out = Path(out)
        from inchworm.plots import save_figure  # noqa: PLC0415

        locs = self.options.localizers

        def draw(axes: Any) -> None:
            for row, loc in enumerate(locs):
                self.plot(axes[row, 0], loc, "inchworm_na_mean")
                self.plot(axes[row, 1], loc, "inchworm_over_ref57")

        return [save_figure(draw, out / "noise.png", (10, 4 * len(locs)), (len(locs), 2), squeeze=False)]


def summarise(rows: list[Row], options: NoiseOptions) -> list[dict[str, Any]]:
    results = []
    for loc, ms, ss in options.settings():
        sel = [r for r in rows if (r["localizer"], r["motion_scale"], r["sensing_scale"]) == (loc, ms, ss)]
        pf = {m: float(np.mean([r["pf"] for r in sel if r["method"] == m])) for m in METHODS}
        results.append({
            "localizer": loc, "motion_scale": ms, "sensing_scale": ss,
            "inchworm_na_mean": float(np.mean([r["n_a_mean"] for r in sel if r["method"] == "inchworm"])),
            "inchworm_na_by_config": anchors_along([r for r in sel if r["method"] == "inchworm"]),
            "drift_pct": {m: float(np.mean([r["drift_pct"] for r in sel if r["method"] == m])) for m in METHODS},
            "pf": pf,
            "inchworm_over_ref57": pf["inchworm"] / pf["ref57"],
            "equal_speed_over_ref57": pf["inchworm-equal-speed"] / pf["ref57"],
            "contacts_per_100": {m: contact_stats([r for r in sel if r["method"] == m])["contacts_per_100"] for m in METHODS},
        })
    return results


def study_noise(
    options: NoiseOptions | None = None,
    *,
    executor: Executor | None = None,
    out: StrPath | None = None,
    resume: bool = False,
    progress: Callable[[int, int], None] | None = None,
) -> NoiseResult:
    """Run the sweep; with ``out`` every run is kept in ``out/runs.jsonl`` and ``out/runs.csv`` as it finishes."""
    options = NoiseOptions() if options is None else options
    log = StudyLog(out, "runs", options_dict(options), resume) if out is not None else None
    rows = run_tasks(run_one, options.tasks(), executor=executor, log=log, progress=progress)
    if log is not None:
        log.finish(rows)
    return NoiseResult(options, rows, summarise(rows, options))
