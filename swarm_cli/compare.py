"""``swarm compare``: Table I/II of the paper for every method on the same random trajectories.

Each trajectory is run by every method with the same seed, so the robots' noise
streams are shared and the comparison is paired. P_f (Eq. 24) per run; per method the
mean, standard deviation and a 97 % confidence interval of the mean (Table II), the
p-value of the paired t-test against ``ref57``, the mean anchor count and the mean
number of steps per configuration (speed), the CPU seconds per run, and the contacts of the
robots' true bodies (``--robot-radius``; per 100 configuration changes, docs/bodies.md). With
``--selections mc,crlb`` the methods that select anchors online run once per ranking
(Monte Carlo e_l or the Cramer-Rao prediction) and are reported as ``method/mc`` and
``method/crlb``. Runs are spread over the machine's cores.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from typing import TYPE_CHECKING

import numpy as np

from coordinator.strategies import METHODS
from runtime.models.config import ModelConfig
from runtime.errors import SwarmInputError
from runtime.models.trajectory import body_spacing, random_trajectory
from swarm_cli.options import SELECTION_METHODS, add_simulation_options, add_workers_option, model_config, print_json, selection_config
from swarm_cli.progress import Progress

if TYPE_CHECKING:  # scipy and matplotlib are imported where used, not to build the parser
    from coordinator.selection.selector import SelectionConfig

REFERENCE = "ref57"
CONFIDENCE = 0.97  # Table II


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("compare", help="Table I/II: P_f of every method on the same random trajectories")
    p.add_argument("--robots", type=int, default=10, help="n_r (default 10)")
    p.add_argument("--trajectories", type=int, default=6, help="random trajectories (default 6; the paper: 100)")
    p.add_argument("--configs", type=int, default=8, help="configurations per trajectory n_d (default 8; the paper: 100)")
    p.add_argument("--methods", default=",".join(METHODS), help=f"comma-separated methods (default: all: {','.join(METHODS)})")
    p.add_argument("--seed", type=int, default=0, help="trajectory t uses seed + t (default 0)")
    p.add_argument("--selections", default=None,
                   help="comma-separated anchor rankings to compare for the searching methods, e.g. mc,crlb (default: --selection)")
    add_workers_option(p)
    p.add_argument("--out", type=Path, default=Path("out/compare"), help="folder for runs.csv and pf.png")
    add_simulation_options(p)
    p.set_defaults(run=run)


def parse_methods(text: str) -> list[str]:
    methods = [m.strip() for m in text.split(",") if m.strip()]
    unknown = [m for m in methods if m not in METHODS]
    if unknown or not methods:
        raise SwarmInputError(f"unknown methods {unknown}; choose from {', '.join(METHODS)}")
    return methods


SEARCHING = ("inchworm", "inchworm-equal-speed")  # methods that rank anchor plans (``--selections``)


def parse_selections(text: str) -> list[str]:
    rankings = [r.strip() for r in text.split(",") if r.strip()]
    if not rankings or any(r not in SELECTION_METHODS for r in rankings):
        raise SwarmInputError(f"--selections must list {' and/or '.join(SELECTION_METHODS)}, got {text!r}")
    return list(dict.fromkeys(rankings))


def run_one(job: tuple) -> dict:
    """One (trajectory, method) run; a top-level function so worker processes can import it."""
    from coordinator.simulate import simulate  # noqa: PLC0415

    t, method, robots, configs, seed, cfg, localizer, selection = job[:8]
    label = job[8] if len(job) > 8 else method
    traj = random_trajectory(robots, configs, np.random.default_rng([seed, t]), sensing_range=cfg.sensing_range_m, **body_spacing(cfg))
    cpu = time.process_time()
    result = simulate(traj, method, cfg, localizer=localizer, selection=selection, seed=seed + t)
    contacts = result.contacts(cfg.robot_radius_m)
    return {
        "trajectory": t,
        "method": label,
        "cpu_s": time.process_time() - cpu,
        "pf": result.pf(),
        "n_a_mean": float(result.anchor_counts().mean()),
        "steps_mean": float(result.steps_per_config().mean()),
        "e_l_final": float(result.localization_errors()[-1]),
        "fallback_steps": sum(1 for s in result.steps if s.fallback),
        "contacts": len(contacts),
        "configs_with_contact": len({c.config for c in contacts}),
        "configs_run": len(result.configs),
        "steps_added": result.steps_added(),
    }


def contact_stats(rows: list[dict]) -> dict:
    """Contacts of the robots' true bodies over ``rows`` (``run_one``'s): per 100 configuration changes, the
    percentage of changes with a contact, and the steps the body constraint added per configuration change."""
    changes = max(sum(r["configs_run"] for r in rows), 1)
    return {"contacts_per_100": 100.0 * sum(r["contacts"] for r in rows) / changes,
            "configs_with_contact_pct": 100.0 * sum(r["configs_with_contact"] for r in rows) / changes,
            "steps_added_per_config": sum(r["steps_added"] for r in rows) / changes}


def summarise(rows: list[dict], methods: list[str]) -> dict:
    """The JSON contract: per-method P_f statistics and p-values against ref57."""
    from scipy import stats  # noqa: PLC0415

    out: dict = {"methods": {}, "p_values": {}}
    by = {m: sorted((r for r in rows if r["method"] == m), key=lambda r: r["trajectory"]) for m in methods}
    for m in methods:
        pf = np.array([r["pf"] for r in by[m]])
        half = stats.t.ppf(0.5 + CONFIDENCE / 2, len(pf) - 1) * pf.std(ddof=1) / np.sqrt(len(pf)) if len(pf) > 1 else float("nan")
        out["methods"][m] = {
            "pf_mean": float(pf.mean()),
            "pf_std": float(pf.std(ddof=1)) if len(pf) > 1 else 0.0,
            "pf_ci97": [float(pf.mean() - half), float(pf.mean() + half)],
            "na_mean": float(np.mean([r["n_a_mean"] for r in by[m]])),
            "steps_mean": float(np.mean([r["steps_mean"] for r in by[m]])),
            "cpu_s_mean": float(np.mean([r["cpu_s"] for r in by[m]])),
            "runs": len(pf),
            **contact_stats(by[m]),
        }
    if REFERENCE in by:
        ref = np.array([r["pf"] for r in by[REFERENCE]])
        for m in methods:
            if m != REFERENCE and len(ref) > 1:
                p = stats.ttest_rel(np.array([r["pf"] for r in by[m]]), ref).pvalue
                out["p_values"][m] = float(p)
    return out


def run(args: argparse.Namespace) -> int:
    cfg = model_config(args)
    methods = parse_methods(args.methods)
    if args.trajectories < 1 or args.configs < 1 or args.robots < 2:
        raise SwarmInputError("--trajectories and --configs must be >= 1 and --robots >= 2")
    selection = selection_config(args)
    rankings = parse_selections(args.selections or selection.method)
    variants = [(m, m, selection) for m in methods if m not in SEARCHING or len(rankings) == 1]
    variants += [(m, f"{m}/{r}", replace(selection, method=r)) for m in methods if m in SEARCHING and len(rankings) > 1 for r in rankings]
    methods = [label for _, label, _ in variants]
    jobs = [(t, m, args.robots, args.configs, args.seed, cfg, args.localizer, sel, label) for t in range(args.trajectories) for m, label, sel in variants]
    progress = Progress(len(jobs), "compare")
    rows = []
    with ProcessPoolExecutor(max_workers=max(1, args.workers)) as pool:
        for row in pool.map(run_one, jobs):
            rows.append(row)
            progress(len(rows))
    from swarm_cli.plots import plot_bars  # noqa: PLC0415 - matplotlib
    from swarm_cli.summary import write_csv  # noqa: PLC0415

    summary = summarise(rows, methods)
    write_csv(args.out / "runs.csv", rows)
    names = list(summary["methods"])
    means = np.array([summary["methods"][m]["pf_mean"] for m in names])
    errs = np.array([summary["methods"][m]["pf_ci97"][1] - summary["methods"][m]["pf_mean"] for m in names])
    title = f"{args.trajectories} trajectories x {args.configs} configurations, n_r = {args.robots} (bars: 97 % CI of the mean)"
    png = plot_bars(names, means, errs, "P_f (Eq. 24)", title, args.out / "pf.png")
    print(f"{'method':<27} {'P_f mean':>9} {'std':>8} {'97% CI':>19} {'n_a':>5} {'steps':>6} {'CPU s':>6} {'p vs ref57':>11} {'contacts/100':>12}")
    for m in names:
        s = summary["methods"][m]
        p = summary["p_values"].get(m)
        print(f"{m:<27} {s['pf_mean']:>9.4f} {s['pf_std']:>8.4f} [{s['pf_ci97'][0]:.4f}, {s['pf_ci97'][1]:.4f}] {s['na_mean']:>5.2f} {s['steps_mean']:>6.2f} {s['cpu_s_mean']:>6.1f} {('-' if p is None else f'{p:.3g}'):>11} {s['contacts_per_100']:>12.2f}")
    if cfg.robot_radius_m > 0:
        print(f"contacts: true bodies of radius {cfg.robot_radius_m:g} m touching, per 100 configuration changes (docs/bodies.md)")
    if "inchworm-equal-speed" in summary["methods"] and REFERENCE in summary["methods"]:
        a, b = summary["methods"]["inchworm-equal-speed"]["pf_mean"], summary["methods"][REFERENCE]["pf_mean"]
        print(f"equal speed (n_a = n_r/2 for both): inchworm-equal-speed / ref57 = {a / b:.3f} (paper, Table I: 0.0477 / 0.0673 = 0.71)")
    print(f"wrote {args.out / 'runs.csv'} and {png}")
    if args.json:
        print_json(summary)
    return 0
