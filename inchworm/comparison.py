"""Table I/II of the paper: P_f of every method on the same random trajectories.

Each trajectory is run by every method with the same seed (``inchworm.seeding``), so the
robots' noise streams are shared and the comparison is paired. P_f (Eq. 24) per run; per
method the mean, standard deviation and a 97 % confidence interval of the mean (Table
II), the p-value of the paired t-test against ``ref57``, the mean anchor count and the
mean number of steps per configuration (speed), the mean n_a at each configuration index (the
anchor count along the trajectory), the drift (final e_l as a percentage of the distance
travelled, as the field reports it) and the CPU seconds per run. With
``selections=("mc", "crlb")`` the methods that select anchors online run once per
ranking and are reported as ``method/mc`` and ``method/crlb``.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from coordinator.strategies import METHODS
from inchworm.limits import check_option_limits
from inchworm.options import RunOptions, check_among, check_at_least, options_dict
from inchworm.runner import Executor, Row, StudyLog, run_tasks
from inchworm.seeding import paired_trajectory, run_seed
from inchworm.stats import CONFIDENCE, clipped_at_zero, mean_ci, paired_p_value
from runtime.models.config import ModelConfig
from runtime.models.trajectory import body_spacing
from runtime.paths import StrPath

if TYPE_CHECKING:
    from matplotlib.axes import Axes

    from coordinator.selection.selector import SelectionConfig

REFERENCE = "ref57"
SEARCHING = ("inchworm", "inchworm-equal-speed")  # methods that rank anchor plans (``selections``)
RANKINGS = ("mc", "crlb")  # coordinator.selection.selector.METHODS, without importing the search


@dataclass(frozen=True)
class RunTask:
    """One (trajectory, method) run of a paired comparison; ``tags`` are prepended to its row."""

    t: int
    method: str
    robots: int
    configs: int
    seed: int
    model: ModelConfig
    localizer: str
    selection: SelectionConfig
    label: str = ""
    tags: tuple[tuple[str, Any], ...] = ()

    @property
    def key(self) -> str:
        return "/".join([*(f"{k}={v!r}" for k, v in self.tags), str(self.t), self.label or self.method])


def run_one(task: RunTask) -> Row:
    """P_f (Eq. 24), mean n_a and n_a per configuration, mean steps per configuration, final e_l (m), drift (final e_l
    / distance travelled, %) and CPU seconds of one run."""
    from coordinator.simulate import simulate  # noqa: PLC0415

    traj = paired_trajectory(task.robots, task.configs, task.seed, task.t, task.model.sensing_range_m, **body_spacing(task.model))
    cpu = time.process_time()
    result = simulate(traj, task.method, task.model, localizer=task.localizer, selection=task.selection, seed=run_seed(task.seed, task.t))
    contacts = result.contacts(task.model.robot_radius_m)
    e_l_final = float(result.localization_errors()[-1])
    return {
        **dict(task.tags),
        "trajectory": task.t,
        "method": task.label or task.method,
        "cpu_s": time.process_time() - cpu,
        "pf": result.pf(),
        "n_a_mean": float(result.anchor_counts().mean()),
        "steps_mean": float(result.steps_per_config().mean()),
        "e_l_final": e_l_final,
        "drift_pct": 100.0 * e_l_final / float(result.travelled()[-1]),
        "n_a_by_config": [int(k) for k in result.anchor_counts()],
        "fallback_steps": sum(1 for s in result.steps if s.fallback),
        "contacts": len(contacts),
        "configs_with_contact": len({c.config for c in contacts}),
        "configs_run": len(result.configs),
        "steps_added": result.steps_added(),
    }




@dataclass(frozen=True, kw_only=True)
class CompareOptions:
    """A paired comparison: ``trajectories`` random trajectories of ``robots`` robots and ``configs`` configurations."""

    robots: int = field(default=10, metadata={"help": "n_r"})
    trajectories: int = field(default=6, metadata={"help": "random trajectories (default %(default)s; the paper: 100)"})
    configs: int = field(default=8, metadata={"help": "configurations per trajectory n_d (default %(default)s; the paper: 100)"})
    methods: tuple[str, ...] = field(default=METHODS, metadata={"help": "comma-separated methods (default: all: %(default)s)"})
    seed: int = field(default=0, metadata={"help": "trajectory t uses seed + t"})
    selections: tuple[str, ...] | None = field(default=None, metadata={  # None: run.selection.method
        "help": "comma-separated anchor rankings to compare for the searching methods, e.g. mc,crlb (default: --selection)"})
    run: RunOptions = field(default_factory=RunOptions)

    def __post_init__(self) -> None:
        check_among(self, "methods", METHODS)
        check_at_least(self, "robots", 2)
        check_at_least(self, "trajectories", 1)
        check_at_least(self, "configs", 1)
        if self.selections is not None:
            check_among(self, "selections", RANKINGS)
        check_option_limits(self)

    def variants(self) -> list[tuple[str, str, SelectionConfig]]:
        """(method, label, selection) of every compared variant, in output order."""
        selection = self.run.selection
        rankings = list(dict.fromkeys(self.selections or (selection.method,)))
        variants = [(m, m, selection) for m in self.methods if m not in SEARCHING or len(rankings) == 1]
        variants += [(m, f"{m}/{r}", replace(selection, method=r)) for m in self.methods if m in SEARCHING and len(rankings) > 1
                     for r in rankings]
        return variants

    def tasks(self) -> list[RunTask]:
        return [RunTask(t, m, self.robots, self.configs, self.seed, self.run.model, self.run.localizer, sel, label)
                for t in range(self.trajectories) for m, label, sel in self.variants()]


def contact_stats(rows: list[Row]) -> dict[str, float]:
    """Contacts of the robots' true bodies over ``rows`` (``run_one``'s, docs/bodies.md): per 100 configuration changes,
    the percentage of changes with a contact, and the steps the body constraint added per configuration change."""
    changes = max(sum(r.get("configs_run", 0) for r in rows), 1)  # rows kept before bodies have none of these keys
    return {"contacts_per_100": 100.0 * sum(r.get("contacts", 0) for r in rows) / changes,
            "configs_with_contact_pct": 100.0 * sum(r.get("configs_with_contact", 0) for r in rows) / changes,
            "steps_added_per_config": sum(r.get("steps_added", 0) for r in rows) / changes}


def anchors_along(rows: list[Row]) -> list[float]:
    """Mean n_a at each configuration index (1, 2, ...) over the runs that reached it."""
    longest = max((len(r["n_a_by_config"]) for r in rows), default=0)
    return [float(np.mean([r["n_a_by_config"][k] for r in rows if len(r["n_a_by_config"]) > k])) for k in range(longest)]


def summarise(rows: list[Row], methods: list[str]) -> dict[str, Any]:
    """Per-method P_f statistics and p-values of the paired t-test against ref57 (rows paired by ``trajectory``)."""
    out: dict[str, Any] = {"methods": {}, "p_values": {}}
    by = {m: sorted((r for r in rows if r["method"] == m), key=lambda r: r["trajectory"]) for m in methods}
    for m in methods:
        pf = np.array([r["pf"] for r in by[m]])
        out["methods"][m] = {
            "pf_mean": float(pf.mean()),
            "pf_std": float(pf.std(ddof=1)) if len(pf) > 1 else 0.0,
            "pf_ci97": list(mean_ci(pf, CONFIDENCE)),
            "na_mean": float(np.mean([r["n_a_mean"] for r in by[m]])),
            "steps_mean": float(np.mean([r["steps_mean"] for r in by[m]])),
            "cpu_s_mean": float(np.mean([r["cpu_s"] for r in by[m]])),
            "drift_pct_mean": float(np.mean([r["drift_pct"] for r in by[m]])),
            "na_by_config": anchors_along(by[m]),
            "runs": len(pf),
            **contact_stats(by[m]),
        }
    if REFERENCE in by:
        ref = np.array([r["pf"] for r in by[REFERENCE]])
        for m in methods:
            if m != REFERENCE and len(ref) > 1:
                out["p_values"][m] = paired_p_value(np.array([r["pf"] for r in by[m]]), ref)
    return out


@dataclass
class CompareResult:
    """Every run (``rows``) and the per-method statistics (``summary``, the ``swarm compare --json`` object)."""

    options: CompareOptions
    rows: list[Row]
    summary: dict[str, Any]

    def to_json(self) -> dict[str, Any]:
        return self.summary

    def report(self) -> str:
        """The table of ``swarm compare``."""
        lines = [f"{'method':<27} {'P_f mean':>9} {'std':>8} {'97% CI':>19} {'n_a':>5} {'steps':>6} {'drift %':>8} {'CPU s':>6} {'p vs ref57':>11} "
                 f"{'contacts/100':>12}"]
        for m, s in self.summary["methods"].items():
            p = self.summary["p_values"].get(m)
            lines.append(f"{m:<27} {s['pf_mean']:>9.4f} {s['pf_std']:>8.4f} [{s['pf_ci97'][0]:.4f}, {s['pf_ci97'][1]:.4f}] {s['na_mean']:>5.2f} "
                         f"{s['steps_mean']:>6.2f} {s['drift_pct_mean']:>8.2f} {s['cpu_s_mean']:>6.1f} {('-' if p is None else f'{p:.3g}'):>11} "
                         f"{s['contacts_per_100']:>12.2f}")
        for m, s in self.summary["methods"].items():
            lines.append(f"n_a along the trajectory, {m}: {' '.join(f'{v:.1f}' for v in s['na_by_config'])}")
        lines.append("drift %: final e_l (true vs estimated, m) / distance travelled (m bar, Eq. 25) x 100")
        methods = self.summary["methods"]
        if "inchworm-equal-speed" in methods and REFERENCE in methods:
            a, b = methods["inchworm-equal-speed"]["pf_mean"], methods[REFERENCE]["pf_mean"]
            lines.append(f"equal speed (n_a = n_r/2 for both): inchworm-equal-speed / ref57 = {a / b:.3f} (paper, Table I: 0.0477 / 0.0673 = 0.71)")
        return "\n".join(lines)

    def plot(self, ax: Axes) -> Axes:
        """P_f per method: mean and 97 % t-interval of the mean, its lower end clipped at 0 (P_f >= 0)."""
        from inchworm.plots import bars  # noqa: PLC0415

        o = self.options
        names = list(self.summary["methods"])
        stats = [self.summary["methods"][m] for m in names]
        intervals = [clipped_at_zero(*s["pf_ci97"]) for s in stats]
        return bars(ax, names, [s["pf_mean"] for s in stats], intervals, "P_f (Eq. 24)",
                    f"{o.trajectories} trajectories x {o.configs} configurations, n_r = {o.robots}",
                    "97 % CI of the mean (t, clipped at 0)")

    def save(self, out: StrPath) -> list[Path]:
        """``pf.png`` in ``out`` (``runs.csv`` is written while the runs finish)."""
        out = Path(out)
        from inchworm.plots import save_figure  # noqa: PLC0415

        return [save_figure(self.plot, out / "pf.png", (max(6.0, 1.3 * len(self.summary["methods"])), 4.4))]


def compare(
    options: CompareOptions | None = None,
    *,
    executor: Executor | None = None,
    out: StrPath | None = None,
    resume: bool = False,
    progress: Callable[[int, int], None] | None = None,
) -> CompareResult:
    """Run the paired comparison; with ``out`` every run is kept in ``out/runs.jsonl`` and ``out/runs.csv`` as it finishes
    (``resume``: continue a comparison interrupted there)."""
    options = CompareOptions() if options is None else options
    log = StudyLog(out, "runs", options_dict(options), resume) if out is not None else None
    rows = run_tasks(run_one, options.tasks(), executor=executor, log=log, progress=progress)
    methods = [label for _, label, _ in options.variants()]
    if log is not None:
        log.finish(rows)
    return CompareResult(options, rows, summarise(rows, methods))
