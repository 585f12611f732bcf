"""``swarm study noise``: where does the online selection choose anchors, and where does it beat ref57?

Sweeps the motion noise (turn and drive sigmas scaled together), the sensing noise
(range and bearing sigmas scaled together) and the localizer. For every setting the
same random trajectories are run by ``inchworm`` and ``ref57`` (and
``inchworm-equal-speed``), recording the mean anchor count the online selection chose
and the P_f ratio against ref57. Heat maps per localizer show both.
"""

from __future__ import annotations

import argparse
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path

import numpy as np

from runtime.errors import SwarmInputError
from swarm_cli.options import add_json_option, add_model_options, add_selection_options, add_workers_option, model_config, parse_list, print_json, selection_config
from swarm_cli.progress import Progress

METHODS = ("inchworm", "inchworm-equal-speed", "ref57")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("noise", help="sweep motion/sensing noise and localizer: chosen n_a and P_f vs ref57")
    p.add_argument("--motion-scales", default="0.5,1,2,4", help="factors on turn and drive sigmas (default 0.5,1,2,4)")
    p.add_argument("--sensing-scales", default="0.25,1,4", help="factors on range and bearing sigmas (default 0.25,1,4)")
    p.add_argument("--localizers", default="paper,joint", help="localizers to sweep (default paper,joint)")
    p.add_argument("--robots", type=int, default=10, help="robots per trajectory (default 10)")
    p.add_argument("--trajectories", type=int, default=3, help="random trajectories per setting (default 3)")
    p.add_argument("--configs", type=int, default=4, help="configurations per trajectory (default 4)")
    p.add_argument("--seed", type=int, default=0, help="seed of the trajectories and noise (default 0)")
    add_workers_option(p)
    p.add_argument("--out", type=Path, default=Path("out/study-noise"), help="folder for the CSV and heat maps (default out/study-noise)")
    add_selection_options(p)
    add_model_options(p)
    add_json_option(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from swarm_cli.compare import contact_stats, run_one  # noqa: PLC0415
    from swarm_cli.summary import write_csv  # noqa: PLC0415
    base = model_config(args)
    motion = parse_list(args.motion_scales, "--motion-scales", float)
    sensing = parse_list(args.sensing_scales, "--sensing-scales", float)
    localizers = [x.strip() for x in args.localizers.split(",") if x.strip()]
    if not localizers or any(x not in ("paper", "joint") for x in localizers):
        raise SwarmInputError(f"--localizers must list paper and/or joint, got {args.localizers!r}")
    selection = selection_config(args)
    settings = [(loc, ms, ss) for loc in localizers for ms in motion for ss in sensing]
    jobs = []
    for loc, ms, ss in settings:
        cfg = replace(base, turn_sigma_rad=base.turn_sigma_rad * ms, drive_sigma_frac=base.drive_sigma_frac * ms,
                      range_sigma_m=base.range_sigma_m * ss, bearing_sigma_rad=base.bearing_sigma_rad * ss)
        jobs += [(t, m, args.robots, args.configs, args.seed, cfg, loc, selection) for t in range(args.trajectories) for m in METHODS]
    progress = Progress(len(jobs), "study noise")
    rows = []
    with ProcessPoolExecutor(max_workers=max(1, args.workers)) as pool:
        for k, row in enumerate(pool.map(run_one, jobs)):
            loc, ms, ss = settings[k // (args.trajectories * len(METHODS))]
            rows.append({"localizer": loc, "motion_scale": ms, "sensing_scale": ss, **row})
            progress(len(rows))
    results = []
    for loc, ms, ss in settings:
        sel = [r for r in rows if (r["localizer"], r["motion_scale"], r["sensing_scale"]) == (loc, ms, ss)]
        pf = {m: float(np.mean([r["pf"] for r in sel if r["method"] == m])) for m in METHODS}
        results.append({
            "localizer": loc, "motion_scale": ms, "sensing_scale": ss,
            "inchworm_na_mean": float(np.mean([r["n_a_mean"] for r in sel if r["method"] == "inchworm"])),
            "pf": pf,
            "inchworm_over_ref57": pf["inchworm"] / pf["ref57"],
            "equal_speed_over_ref57": pf["inchworm-equal-speed"] / pf["ref57"],
            "contacts_per_100": {m: contact_stats([r for r in sel if r["method"] == m])["contacts_per_100"] for m in METHODS},
        })
    write_csv(args.out / "runs.csv", rows)
    png = plot_heatmaps(results, localizers, motion, sensing, args.out / "noise.png")
    print(f"{'localizer':<9} {'motion x':>8} {'sensing x':>9} {'n_a chosen':>10} {'P_f inchworm/ref57':>19} {'equal-speed/ref57':>18}")
    for r in results:
        print(f"{r['localizer']:<9} {r['motion_scale']:>8g} {r['sensing_scale']:>9g} {r['inchworm_na_mean']:>10.2f} {r['inchworm_over_ref57']:>19.3f} {r['equal_speed_over_ref57']:>18.3f}")
    print(f"wrote {args.out / 'runs.csv'} and {png}")
    if args.json:
        print_json({"results": results, "trajectories": args.trajectories, "configs": args.configs, "robots": args.robots})
    return 0


def plot_heatmaps(results: list[dict], localizers: list[str], motion: list[float], sensing: list[float], path: Path) -> Path:
    """Per localizer: the chosen n_a and the P_f ratio inchworm / ref57 over (motion, sensing) scales."""
    import matplotlib  # noqa: PLC0415 - plotting and the search only when a command runs (fast --help)
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415
    fig, axes = plt.subplots(len(localizers), 2, figsize=(10, 4 * len(localizers)), squeeze=False)
    for row, loc in enumerate(localizers):
        for col, (key, title, cmap) in enumerate((("inchworm_na_mean", "n_a chosen by inchworm", "viridis"),
                                                  ("inchworm_over_ref57", "P_f inchworm / ref57 (< 1: inchworm better)", "RdBu_r"))):
            grid = np.array([[next(r[key] for r in results if r["localizer"] == loc and r["motion_scale"] == m and r["sensing_scale"] == s)
                              for s in sensing] for m in motion])
            ax = axes[row, col]
            kwargs = {"vmin": 0.5, "vmax": 1.5} if key == "inchworm_over_ref57" else {}
            im = ax.imshow(grid, cmap=cmap, origin="lower", aspect="auto", **kwargs)
            for (i, j), v in np.ndenumerate(grid):
                ax.text(j, i, f"{v:.2f}", ha="center", va="center", color="white" if key == "inchworm_na_mean" else "black")
            ax.set_xticks(range(len(sensing)), [f"{s:g}" for s in sensing])
            ax.set_yticks(range(len(motion)), [f"{m:g}" for m in motion])
            ax.set_xlabel("sensing noise scale")
            ax.set_ylabel("motion noise scale")
            ax.set_title(f"{loc}: {title}")
            fig.colorbar(im, ax=ax)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
