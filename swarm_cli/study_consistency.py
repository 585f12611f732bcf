"""``swarm study consistency``: is the reported uncertainty honest? Position NEES along trajectories.

Every (localizer, method) runs the same random trajectories in the in-process simulator;
after each configuration the position NEES / 2 (``coordinator.consistency``) is averaged
over robots and trajectories and plotted per configuration with its chi-square band
(PNG). Near 1: the covariances match the errors; above: overconfident; below: pessimistic.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from typing import TYPE_CHECKING

import numpy as np

from runtime.errors import SwarmInputError
from coordinator.localization.registry import BUILTIN_LOCALIZERS
from swarm_cli.options import add_json_option, add_model_options, add_selection_options, localizer_list, model_config, print_json, selection_config
from swarm_cli.progress import Progress

if TYPE_CHECKING:  # annotations only: the search and plotting are imported when a command runs
    from coordinator.consistency import ConsistencyRow


METHODS = ("no-anchors", "ref57", "heuristic-fixed", "one-at-a-time")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("consistency", help="NEES of the reported position covariance along trajectories, per localizer and method")
    p.add_argument("--localizers", default=",".join(BUILTIN_LOCALIZERS),
                   help=f"comma-separated, any registered localizer (default {','.join(BUILTIN_LOCALIZERS)})")
    p.add_argument("--methods", default=",".join(METHODS), help=f"comma-separated anchor methods (default {','.join(METHODS)})")
    p.add_argument("--robots", type=int, default=10, help="n_r (default 10)")
    p.add_argument("--configs", type=int, default=100, help="configurations per trajectory (default 100)")
    p.add_argument("--trajectories", type=int, default=48,
                   help="random trajectories (default 48: with 16 a consistent filter leaves [0.7, 1.5] at some configuration quite often)")
    p.add_argument("--seed", type=int, default=0, help="seed of the trajectories and the noise (default 0)")
    p.add_argument("--out", type=Path, default=Path("out/study-consistency"), help="output folder for the PNG")
    add_selection_options(p)
    add_model_options(p)
    add_json_option(p)
    p.set_defaults(run=run)


def _names(text: str, flag: str, allowed: tuple[str, ...]) -> tuple[str, ...]:
    names = tuple(x.strip() for x in text.split(",") if x.strip())
    bad = [x for x in names if x not in allowed]
    if not names or bad:
        raise SwarmInputError(f"{flag}: unknown {bad or text!r}; choose from {', '.join(allowed)}")
    return names


def run(args: argparse.Namespace) -> int:
    from coordinator.strategies import METHODS as ALL_METHODS  # noqa: PLC0415
    from coordinator.consistency import chi2_band, consistency_study  # noqa: PLC0415
    localizers = tuple(localizer_list(args.localizers, "--localizers"))
    methods = _names(args.methods, "--methods", tuple(ALL_METHODS))
    for flag, value, low in (("--robots", args.robots, 2), ("--configs", args.configs, 1), ("--trajectories", args.trajectories, 1)):
        if value < low:
            raise SwarmInputError(f"{flag} must be >= {low}, got {value}")
    progress = Progress(len(localizers) * len(methods) * args.trajectories, "study consistency")
    rows = consistency_study(
        model_config(args), localizers=localizers, methods=methods, robots=args.robots, configs=args.configs,
        trajectories=args.trajectories, seed=args.seed, selection=selection_config(args), progress=progress,
    )
    band = chi2_band(args.robots, args.trajectories)
    args.out.mkdir(parents=True, exist_ok=True)
    png = plot(rows, band, args.out / "consistency.png")
    summaries = [r.summary() for r in rows]
    print(f"position NEES / 2 per configuration, mean over {args.trajectories} trajectories of {args.robots} robots"
          f" (chi-square 95 % band {band[0]:.2f}-{band[1]:.2f} if errors were independent; target 0.7-1.5)")
    print(f"{'localizer':<9} {'method':<16} {'configs':>7} {'median':>8} {'max':>8} {'min':>8}")
    for s in summaries:
        med, mx, mn = s["nees_over_expected_median"], s["nees_over_expected_max"], s["nees_over_expected_min"]
        print(f"{s['localizer']:<9} {s['method']:<16} {s['configs']:>7} {_fmt(med):>8} {_fmt(mx):>8} {_fmt(mn):>8}")
    print(f"wrote {png}")
    if args.json:
        print_json({"rows": summaries})
    return 0


def _fmt(x: float | None) -> str:
    return "inf" if x is None else f"{x:.3g}"


def plot(rows: list[ConsistencyRow], band: tuple[float, float], path: Path) -> Path:
    """One panel per localizer: NEES / 2 per configuration for every method, with the chi-square band."""
    import matplotlib  # noqa: PLC0415 - plotting and the search only when a command runs (fast --help)
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415
    localizers = sorted({r.localizer for r in rows}, key=[r.localizer for r in rows].index)
    fig, axes = plt.subplots(1, len(localizers), figsize=(6.5 * len(localizers), 4.5), squeeze=False, sharey=True)
    for ax, loc in zip(axes[0], localizers):
        k = 0
        for r in rows:
            if r.localizer != loc:
                continue
            k = len(r.per_config)
            ax.plot(np.arange(1, k + 1), np.clip(r.per_config, 1e-3, 1e6), label=r.method)
        ax.axhspan(*band, color="0.85", label="chi-square 95 % band")
        ax.axhline(1.0, color="k", lw=0.8)
        ax.axhspan(0.7, 1.5, fill=False, ls="--", ec="tab:green", label="target 0.7-1.5")
        ax.set_yscale("log")
        ax.set_xlabel("configuration")
        ax.set_title(f"{loc} localizer")
        ax.set_xlim(1, max(k, 2))
    axes[0, 0].set_ylabel("position NEES / 2 (mean over robots and trajectories)")
    axes[0, -1].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
