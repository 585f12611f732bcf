"""What ``swarm sim`` and ``swarm coordinator`` print and write about a finished run."""

from __future__ import annotations

import csv
from pathlib import Path

from coordinator.executor import RunResult, StepRecord


def print_config_table(result: RunResult) -> tuple[list[dict], list[StepRecord]]:
    """Print the per-configuration table (n_a, steps, e_l, following error, distance) and the
    steps that kept dead reckoning; return the table's rows (empty without ground truth) and those steps."""
    rows = []
    if result.has_truth:
        e_l, follow, travelled = result.localization_errors(), result.following_errors(), result.travelled()
    print(f"{'config':>6} {'n_a':>4} {'steps':>5} {'e_l (mm)':>9} {'follow (mm)':>11} {'travelled (m)':>13}")
    for c, rec in enumerate(result.configs):
        if result.has_truth:
            print(f"{c + 1:>6} {rec.plan.n_anchors:>4} {rec.plan.n_steps:>5} {e_l[c] * 1e3:>9.2f} {follow[c] * 1e3:>11.2f} {travelled[c]:>13.3f}")
            rows.append({"config": c + 1, "n_a": rec.plan.n_anchors, "steps": rec.plan.n_steps, "e_l": float(e_l[c]),
                         "following_error": float(follow[c]), "travelled": float(travelled[c])})
        else:
            print(f"{c + 1:>6} {rec.plan.n_anchors:>4} {rec.plan.n_steps:>5} {'-':>9} {'-':>11} {'-':>13}")
    fallbacks = [s for s in result.steps if s.fallback]
    for s in fallbacks:
        print(f"config {s.config + 1} step {s.step + 1}: kept dead reckoning ({s.fallback})")
    print_anchor_choices(result)
    return rows, fallbacks


def print_anchor_choices(result: RunResult) -> None:
    """Per configuration: which robots stood still at each step and, where the plan was searched,
    the outer loop's score of every candidate count (Eq. 3: P_s = w_v P_v - w_l P_l, P_v = 1 / n_s,
    P_l = e_l / e_l(0), e_l the Monte Carlo estimate of the count's best plan, in mm)."""
    from swarm_cli.agent import format_ids  # noqa: PLC0415

    for c in result.configs:
        plan = c.plan
        still = "; ".join(f"step {k + 1}: {_robots(sorted(c.anchor_ids(k).tolist()), format_ids)}" for k in range(plan.n_steps))
        who = "no anchors, every robot moved at once" if plan.n_anchors == 0 else f"stood still {still}"
        print(f"config {c.config + 1}: n_a = {plan.n_anchors} ({who})")
        if c.selection is None or len(c.selection.scores) < 2:
            continue
        print(f"  {'n_a':>5} {'steps':>5} {'e_l (mm)':>9} {'P_v':>6} {'P_l':>6} {'P_s':>7}")
        for s in c.selection.scores:
            mark = "*" if s.n_anchors == plan.n_anchors else " "
            steps = round(1 / s.p_v) if s.p_v > 0 else 0
            if s.plan is None:
                print(f"  {mark}{s.n_anchors:>4} {steps:>5} {'no plan keeps the swarm connected':>30}")
            else:
                print(f"  {mark}{s.n_anchors:>4} {steps:>5} {s.e_l * 1e3:>9.2f} {s.p_v:>6.3f} {s.p_l:>6.3f} {s.p_s:>7.3f}")
    if any(c.selection is not None and len(c.selection.scores) > 1 for c in result.configs):
        print("  (* chosen: the count of highest P_s = w_v P_v - w_l P_l, Eq. 3; P_v = 1/steps; P_l = e_l / e_l(n_a = 0)"
              " on the same samples; e_l: Monte Carlo estimate of the count's best plan)")


def _robots(ids: list[int], format_ids, most: int = 20) -> str:
    """Robot ids as ranges (``0-3,7``); a long list as its count and first ids."""
    if not ids:
        return "none"
    return format_ids(ids) if len(ids) <= most else f"{len(ids)} robots ({format_ids(ids[:most])}, ...)"


def write_plots(result: RunResult, out: Path) -> list[str]:
    """``trajectory.png`` (Fig. 13/14) and, with ground truth, ``errors.png`` (Fig. 17) in ``out``."""
    from swarm_cli.plots import plot_errors, plot_trajectory  # matplotlib only when plotting

    out.mkdir(parents=True, exist_ok=True)
    plots = [str(plot_trajectory(result, out / "trajectory.png"))]
    if result.has_truth:
        plots.append(str(plot_errors(result, out / "errors.png")))
    return plots


def write_csv(path: Path, rows: list[dict]) -> Path:
    """``rows`` (dicts with the same keys, in column order) as a CSV file with a header; creates the folder."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    return path
