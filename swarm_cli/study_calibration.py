"""``swarm study calibration``: at which noise does ref57's P_f match the paper's Table I, and what then?

The paper states no noise levels. For each localizer and sensing-noise scale, the motion
noise scale (turn and drive sigmas together) at which ref57's mean P_f (Eq. 24) equals
``--target`` (the paper's 0.0673) is found by bisection on log(scale) over
``--calibration-trajectories`` random trajectories (their own seeds, not used again).
There the methods run on every seed set of ``--seeds`` (``--trajectories`` each, paired:
every method on the same trajectories and noise streams); per seed set and pooled, the
P_f ratio against ref57 and the paired t-test p-value. P_f falls with trajectory length
(the final error grows more slowly than the distance travelled), so the calibrated noise
holds for ``--configs`` configurations, not for the paper's 100.
"""

from __future__ import annotations

import argparse
import math
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path

import numpy as np

from runtime.models.config import ModelConfig
from runtime.errors import SwarmInputError
from swarm_cli.options import add_json_option, add_model_options, add_selection_options, add_workers_option, model_config, parse_list, positive_int, print_json, selection_config
from swarm_cli.progress import Progress

PAPER_REF57_PF = 0.0673  # Table I, ref. [57]
CALIBRATION_SEED = 10**6  # calibration trajectories use seeds CALIBRATION_SEED + t


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("calibration", help="noise at which ref57's P_f matches the paper's; inchworm / ref57 there")
    p.add_argument("--localizers", default="paper,joint", help="localizers (default paper,joint)")
    p.add_argument("--sensing-scales", default="1", help="factors on range and bearing sigmas (default 1)")
    p.add_argument("--target", type=float, default=PAPER_REF57_PF, help="ref57 P_f to match (default the paper's 0.0673)")
    p.add_argument("--max-motion-scale", type=float, default=32.0, help="largest factor on turn and drive sigmas tried (default 32)")
    p.add_argument("--calibration-trajectories", type=int, default=12, help="ref57 trajectories per bisection step (default 12)")
    p.add_argument("--iterations", type=int, default=7, help="bisection steps on log(motion scale) (default 7)")
    p.add_argument("--robots", type=positive_int, default=10, help="robots per trajectory (default 10)")
    p.add_argument("--trajectories", type=int, default=30, help="trajectories per seed set (default 30)")
    p.add_argument("--configs", type=int, default=15, help="configurations per trajectory (default 15)")
    p.add_argument("--seeds", default="0,1000", help="seed sets; trajectory t of set s uses seed s + t (default 0,1000)")
    p.add_argument("--methods", default="inchworm,inchworm-equal-speed,ref57",
                   help="comma-separated methods compared with ref57 at the calibrated noise (default inchworm,inchworm-equal-speed,ref57)")
    add_workers_option(p)
    p.add_argument("--out", type=Path, default=Path("out/study-calibration"), help="folder for the CSV and PNG (default out/study-calibration)")
    add_selection_options(p)
    add_model_options(p)
    add_json_option(p)
    p.set_defaults(run=run)


def scaled(base: ModelConfig, motion: float, sensing: float) -> ModelConfig:
    return replace(base, turn_sigma_rad=base.turn_sigma_rad * motion, drive_sigma_frac=base.drive_sigma_frac * motion,
                   range_sigma_m=base.range_sigma_m * sensing, bearing_sigma_rad=base.bearing_sigma_rad * sensing)


def _run(jobs: list[tuple], pool: ProcessPoolExecutor) -> list[dict]:
    from swarm_cli.compare import run_one  # noqa: PLC0415
    return list(pool.map(run_one, jobs))


def calibrate(base: ModelConfig, localizer: str, sensing: float, args: argparse.Namespace, selection, pool) -> tuple[float, float]:
    """(motion scale, ref57 mean P_f there): bisection on log(scale) in [1, --max-motion-scale]."""
    from swarm_cli.compare import REFERENCE  # noqa: PLC0415

    def pf(motion: float) -> float:
        cfg = scaled(base, motion, sensing)
        jobs = [(t, REFERENCE, args.robots, args.configs, CALIBRATION_SEED, cfg, localizer, selection) for t in range(args.calibration_trajectories)]
        return float(np.mean([r["pf"] for r in _run(jobs, pool)]))

    lo, hi = 0.0, math.log(args.max_motion_scale)
    for _ in range(args.iterations):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if pf(math.exp(mid)) < args.target else (lo, mid)
    motion = math.exp(0.5 * (lo + hi))
    return motion, pf(motion)


def compare_at(cfg: ModelConfig, localizer: str, methods: list[str], seeds: list[int], args, selection, pool, tick) -> tuple[dict, list[dict]]:
    """Per seed set and pooled: P_f per method, ratio to ref57 and paired p-values."""
    from swarm_cli.compare import REFERENCE, run_one, summarise  # noqa: PLC0415
    rows: list[dict] = []
    for s in seeds:
        jobs = [(t, m, args.robots, args.configs, s, cfg, localizer, selection) for t in range(args.trajectories) for m in methods]
        for row in pool.map(run_one, jobs):
            rows.append({"seed_set": s, **row})
            tick()
    out: dict = {}
    for label, subset in [(str(s), [r for r in rows if r["seed_set"] == s]) for s in seeds] + [("pooled", rows)]:
        keyed = [{**r, "trajectory": (r["seed_set"], r["trajectory"])} for r in subset]
        summary = summarise(keyed, methods)
        ref = summary["methods"][REFERENCE]["pf_mean"]
        out[label] = {
            "pf": {m: summary["methods"][m]["pf_mean"] for m in methods},
            "na": {m: summary["methods"][m]["na_mean"] for m in methods},
            "over_ref57": {m: summary["methods"][m]["pf_mean"] / ref for m in methods if m != REFERENCE},
            "p_values": summary["p_values"],
            "trajectories": len(subset) // len(methods),
            "contacts_per_100": {m: summary["methods"][m]["contacts_per_100"] for m in methods},
        }
    return out, rows


def run(args: argparse.Namespace) -> int:
    from swarm_cli.compare import REFERENCE, parse_methods  # noqa: PLC0415
    from swarm_cli.summary import write_csv  # noqa: PLC0415
    base = model_config(args)
    selection = selection_config(args)
    sensing = parse_list(args.sensing_scales, "--sensing-scales", float)
    seeds = parse_list(args.seeds, "--seeds", int)
    methods = parse_methods(args.methods)
    localizers = [x.strip() for x in args.localizers.split(",") if x.strip()]
    if not localizers or any(x not in ("paper", "joint") for x in localizers):
        raise SwarmInputError(f"--localizers must list paper and/or joint, got {args.localizers!r}")
    if REFERENCE not in methods:
        raise SwarmInputError(f"--methods must include {REFERENCE} (the ratios are against it)")
    if min(args.trajectories, args.configs, args.calibration_trajectories, args.iterations) < 1 or args.target <= 0 or args.max_motion_scale <= 1:
        raise SwarmInputError("--trajectories, --configs, --calibration-trajectories, --iterations must be >= 1, --target > 0, --max-motion-scale > 1")
    settings = [(loc, ss) for loc in localizers for ss in sensing]
    progress = Progress(len(settings) * len(seeds) * args.trajectories * len(methods), "study calibration")
    done = [0]

    def tick() -> None:
        done[0] += 1
        progress(done[0])

    results, all_rows = [], []
    with ProcessPoolExecutor(max_workers=max(1, args.workers)) as pool:
        for loc, ss in settings:
            motion, pf_cal = calibrate(base, loc, ss, args, selection, pool)
            print(f"{loc}, sensing x {ss:g}: ref57 P_f = {pf_cal:.4f} at motion noise x {motion:.2f} (calibration set)", flush=True)
            stats, rows = compare_at(scaled(base, motion, ss), loc, methods, seeds, args, selection, pool, tick)
            all_rows += [{"localizer": loc, "sensing_scale": ss, "motion_scale": motion, **r} for r in rows]
            results.append({"localizer": loc, "sensing_scale": ss, "motion_scale": motion, "ref57_pf_calibration": pf_cal, **stats})
    write_csv(args.out / "runs.csv", all_rows)
    print(f"{'localizer':<9} {'sensing x':>9} {'motion x':>8} {'seeds':>8} {'ref57 P_f':>10} " + " ".join(f"{m + ' / ref57':>28} {'p':>6}" for m in methods if m != REFERENCE))
    for r in results:
        for label in [str(s) for s in seeds] + ["pooled"]:
            s = r[label]
            cells = " ".join(f"{s['over_ref57'][m]:>28.3f} {s['p_values'].get(m, float('nan')):>6.3f}" for m in methods if m != REFERENCE)
            print(f"{r['localizer']:<9} {r['sensing_scale']:>9g} {r['motion_scale']:>8.2f} {label:>8} {s['pf'][REFERENCE]:>10.4f} {cells}")
    print(f"({args.trajectories} trajectories x {args.configs} configurations per seed set, n_r = {args.robots}; wrote {args.out / 'runs.csv'})")
    if args.json:
        print_json({"results": results, "seeds": seeds, "trajectories": args.trajectories, "configs": args.configs, "target": args.target})
    return 0
