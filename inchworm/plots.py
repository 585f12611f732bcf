"""Plots of runs and studies, drawn on a matplotlib ``Axes`` the caller owns (a notebook, a talk figure).

Nothing here chooses a matplotlib backend: ``save_figure`` draws on a ``matplotlib.figure.Figure``
(no pyplot), which writes PNG files with any backend or none.
"""

from __future__ import annotations

import textwrap
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from runtime.errors import OutputError
from runtime.paths import StrPath

if TYPE_CHECKING:
    from matplotlib.axes import Axes

    from coordinator.run_result import RunResult

DESIRED, ESTIMATED, TRUE = "tab:red", "tab:green", "tab:blue"


def title(ax: Axes, text: str, fontsize: float = 11) -> None:
    """``text`` as the title of ``ax``, wrapped to the axes' width (never cut)."""
    fig = ax.get_figure(root=True)
    width_in = fig.get_size_inches()[0] * ax.get_position().width if fig is not None else 6.0
    chars = max(20, int(width_in * 72 / (0.5 * fontsize)))
    ax.set_title("\n".join(textwrap.wrap(text, chars)), fontsize=fontsize)


def save_figure(draw: Callable[..., Any], path: StrPath, size: tuple[float, float], panels: tuple[int, int] = (1, 1), **kw: Any) -> Path:
    """A new figure of ``size`` inches with ``panels`` (rows, columns) of axes (``kw``: to ``Figure.subplots``),
    ``draw(axes)`` on it, saved as ``path``."""
    from matplotlib.figure import Figure  # noqa: PLC0415

    fig = Figure(figsize=size, layout="constrained")
    axes = fig.subplots(*panels, **kw)
    draw(axes)
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=110)
    except OSError as exc:
        raise OutputError(f"cannot write {path}: {exc.strerror or exc}") from None
    return path


def bars(ax: Axes, names: Sequence[str], means: Sequence[float], intervals: Sequence[tuple[float, float]], ylabel: str,
         heading: str, interval_label: str) -> Axes:
    """Bars of ``means`` with error bars from ``intervals`` (low, high); the y-axis starts at 0."""
    means_a = np.asarray(means, float)
    iv = np.asarray(intervals, float).reshape(-1, 2)
    err = np.vstack([means_a - iv[:, 0], iv[:, 1] - means_a])
    ax.bar(names, means_a, color="tab:gray", label="mean")
    ax.errorbar(names, means_a, yerr=np.nan_to_num(err), fmt="none", ecolor="black", capsize=4, label=interval_label)
    ax.set_ylabel(ylabel)
    ax.set_ylim(bottom=0)
    ax.tick_params(axis="x", rotation=20)
    ax.legend(loc="upper right", fontsize=8)
    title(ax, heading)
    return ax


def plot_trajectory(run: RunResult, ax: Axes) -> Axes:
    """Fig. 13/14/16: desired (red), estimated (green) and true (blue) configurations of ``run``.

    Hollow circles: earlier configurations; filled circles: the last one; black rings: the
    anchors of each configuration's first step, where they stood (the estimate at the start of
    that configuration); x: the start estimate.
    """
    from matplotlib.collections import LineCollection  # noqa: PLC0415
    from matplotlib.lines import Line2D  # noqa: PLC0415

    desired = run.desired_configurations()
    estimated = run.estimated_configurations()
    series = [("desired", DESIRED, desired), ("estimated", ESTIMATED, estimated[1:])]
    if run.has_truth:
        truths = run.true_configurations()
        series.append(("true", TRUE, truths))
        ax.add_collection(LineCollection(list(truths.swapaxes(0, 1)), colors=TRUE, linewidths=0.5, alpha=0.4))  # one artist: 10,000 robots
    for _label, color, configs in series:
        x, y = configs[:-1].reshape(-1, 2).T
        ax.scatter(x, y, s=22, facecolors="none", edgecolors=color, linewidths=0.8)
        x, y = configs[-1][:, :2].T
        ax.scatter(x, y, s=40, color=color)
    for k, c in enumerate(run.configs):  # where the anchors stood: the estimate at the start of their configuration
        before = run.configs[k - 1].estimate if k else run.initial_estimate
        anchors = np.isin(before.ids, c.anchor_ids(0))
        x, y = before.positions[anchors].T
        ax.scatter(x, y, s=90, facecolors="none", edgecolors="black", linewidths=0.8)
    x, y = run.initial_estimate.positions.T
    ax.scatter(x, y, s=30, marker="x", color="gray")
    dot: dict[str, Any] = dict(marker="o", ls="none")
    handles = [Line2D([], [], color=color, ms=7, label=label, **dot) for label, color, _ in series]
    handles += [
        Line2D([], [], mfc="none", mec="0.3", ms=6, label="earlier configurations (hollow)", **dot),
        Line2D([], [], color="0.3", ms=7, label="last configuration (filled)", **dot),
        Line2D([], [], mfc="none", mec="black", ms=10, label="anchors of a configuration's first step", **dot),
        Line2D([], [], marker="x", ls="none", color="gray", label="start estimate"),
    ]
    if run.has_truth:
        handles.append(Line2D([], [], color=TRUE, lw=0.8, alpha=0.6, label="true paths"))
    ax.legend(handles=handles, loc="best", fontsize=8)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    counts = run.anchor_counts()
    title(ax, f"{run.method}: {len(run.configs)} configurations, n_a per configuration {counts.min()}..{counts.max()}"
          + (f", P_f = {run.pf():.4f}" if run.has_truth else ""))
    return ax


def plot_errors(runs: RunResult | Mapping[str, RunResult], axes: Sequence[Axes]) -> Sequence[Axes]:
    """Fig. 17 on two axes: (a) localization error e_l and (b) trajectory-following error (mm) against the
    average distance travelled (m), one line per run of ``runs`` (a run or {label: run}); both axes from 0."""
    if not isinstance(runs, Mapping):
        runs = {runs.method: runs}
    for ax, key, heading in ((axes[0], "localization_errors", "(a) localization error e_l"),
                             (axes[1], "following_errors", "(b) trajectory-following error")):
        for label, run in runs.items():
            ax.plot(run.travelled(), getattr(run, key)() * 1000, "o-", ms=3, label=f"{label} (P_f = {run.pf():.4f})")
        ax.set_xlabel("average distance travelled (m)")
        ax.set_ylabel("error (mm)")
        ax.set_xlim(left=0)
        ax.set_ylim(bottom=0)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
        title(ax, heading)
    return axes


def write_run_plots(run: RunResult, out: StrPath, compared: Mapping[str, RunResult] | None = None) -> list[str]:
    """``trajectory.png`` (Fig. 13/14) and, with ground truth, ``errors.png`` (Fig. 17; with ``compared`` runs beside it)."""
    out = Path(out)
    plots = [str(save_figure(lambda ax: plot_trajectory(run, ax), out / "trajectory.png", (7.5, 7.5)))]
    if run.has_truth:
        runs = {run.method: run, **(compared or {})}
        plots.append(str(save_figure(lambda axes: plot_errors(runs, axes), out / "errors.png", (11, 4.2), (1, 2))))
    return plots
