"""PNG plots in the style of the paper's figures (matplotlib, no display needed)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from coordinator.executor import RunResult  # noqa: E402

DESIRED, ESTIMATED, TRUE = "tab:red", "tab:green", "tab:blue"


def plot_trajectory(run: RunResult, path: Path) -> Path:
    """Fig. 13/14/16: desired (red), estimated (green) and true (blue) configurations.

    Hollow circles are past configurations, filled circles the last one; the anchors of
    each configuration's first step are ringed in black where they stood (the estimate at the
    start of that configuration); the legend names every marker.
    """
    k = len(run.configs)
    desired = run.desired_configurations()
    estimated = run.estimated_configurations()
    fig, ax = plt.subplots(figsize=(7, 7))
    for label, color, configs in (("desired", DESIRED, desired), ("estimated", ESTIMATED, estimated[1:])):
        ax.scatter(*configs[:-1].reshape(-1, 2).T, s=22, facecolors="none", edgecolors=color, linewidths=0.8)
        ax.scatter(*configs[-1].T, s=40, color=color, label=label)
    if run.has_truth:
        truths = run.true_configurations()
        ax.scatter(*truths[:-1].reshape(-1, 2).T, s=22, facecolors="none", edgecolors=TRUE, linewidths=0.8)
        ax.scatter(*truths[-1].T, s=40, color=TRUE, label="true")
        for i in range(truths.shape[1]):
            ax.plot(truths[:, i, 0], truths[:, i, 1], color=TRUE, lw=0.5, alpha=0.4)
    label = "anchor: stood still in its configuration's first step"
    for j, c in enumerate(run.configs):  # where the anchors stood: the estimate at the start of their configuration
        before = run.configs[j - 1].estimate if j else run.initial_estimate
        anchors = np.isin(before.ids, c.anchor_ids(0))
        if anchors.any():
            ax.scatter(*before.positions[anchors].T, s=110, facecolors="none", edgecolors="black", linewidths=1.0, label=label)
            label = None
    ax.scatter(*run.initial_estimate.positions.T, s=30, marker="x", color="gray", label="start (estimated)")
    ax.scatter([], [], s=22, facecolors="none", edgecolors="gray", linewidths=0.8, label="hollow: earlier configurations")
    if run.has_truth:
        ax.plot([], [], color=TRUE, lw=0.5, alpha=0.4, label="true path of each robot")
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    anchors = run.anchor_counts()
    ax.set_title(f"{run.method}: {k} configurations, n_a per configuration {anchors.min()}..{anchors.max()}" + (f", P_f = {run.pf():.4f}" if run.has_truth else ""))
    ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_errors(run: RunResult, path: Path) -> Path:
    """Fig. 17: (a) localization error and (b) trajectory-following error vs average distance travelled."""
    travelled = run.travelled()
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for ax, values, title in (
        (axes[0], run.localization_errors(), "(a) localization error e_l"),
        (axes[1], run.following_errors(), "(b) trajectory-following error"),
    ):
        ax.plot(travelled, values * 1000, "o-", ms=3)
        ax.set_xlabel("average total motion (m)")
        ax.set_ylabel("error (mm)")
        ax.set_title(title)
        ax.grid(alpha=0.3)
    fig.suptitle(f"{run.method}")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_bars(names: list[str], means: np.ndarray, errs: np.ndarray, ylabel: str, title: str, path: Path) -> Path:
    """Bar chart with error bars (e.g. P_f per method)."""
    fig, ax = plt.subplots(figsize=(max(6, 1.3 * len(names)), 4))
    ax.bar(names, means, yerr=errs, capsize=4, color="tab:gray")
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.tick_params(axis="x", rotation=20)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
