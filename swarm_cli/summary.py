"""What ``swarm sim`` and ``swarm coordinator`` print and write about a finished run."""

from __future__ import annotations

import csv
from pathlib import Path

from coordinator.executor import RunResult, StepRecord


def print_config_table(result: RunResult) -> tuple[list[dict], list[StepRecord]]:
    """Print the per-configuration table (n_a of the strategy's plan, steps taken, e_l, following error, distance),
    where the body constraint regrouped a plan a line saying so, and the
    steps that kept dead reckoning; return the table's rows (empty without ground truth) and those steps."""
    rows = []
    if result.has_truth:
        e_l, follow, travelled = result.localization_errors(), result.following_errors(), result.travelled()
    print(f"{'config':>6} {'n_a':>4} {'steps':>5} {'e_l (mm)':>9} {'follow (mm)':>11} {'travelled (m)':>13}")
    anchors = result.anchor_counts()
    for c, rec in enumerate(result.configs):
        if result.has_truth:
            print(f"{c + 1:>6} {anchors[c]:>4} {rec.plan.n_steps:>5} {e_l[c] * 1e3:>9.2f} {follow[c] * 1e3:>11.2f} {travelled[c]:>13.3f}")
            rows.append({"config": c + 1, "n_a": int(anchors[c]), "steps": rec.plan.n_steps, "e_l": float(e_l[c]),
                         "following_error": float(follow[c]), "travelled": float(travelled[c])})
        else:
            print(f"{c + 1:>6} {anchors[c]:>4} {rec.plan.n_steps:>5} {'-':>9} {'-':>11} {'-':>13}")
    for c, rec in enumerate(result.configs):
        if rec.regrouped is not None:
            print(f"config {c + 1}: {rec.regrouped.describe(rec.plan.n_steps)}")
    fallbacks = [s for s in result.steps if s.fallback]
    for s in fallbacks:
        print(f"config {s.config + 1} step {s.step + 1}: kept dead reckoning ({s.fallback})")
    return rows, fallbacks


def print_contacts(result: RunResult, radius: float) -> dict:
    """Print the contacts of the robots' true bodies (radius ``radius`` m) and return the additive ``--json`` keys:
    ``robot_radius_m``, ``contacts`` (each ``step``, ``config`` 1-based, ``robots`` [a, b], ``distance_m``) and
    ``steps_added`` (by the body constraint)."""
    contacts = result.contacts(radius)
    if radius > 0 and result.has_truth:
        closest = f", closest {min(c.distance for c in contacts) * 1e3:.1f} mm" if contacts else ""
        print(f"contacts (bodies of radius {radius:g} m): {len(contacts)}{closest}; steps added for bodies: {result.steps_added()}")
        for c in contacts:
            print(f"  step {c.step} (config {c.config + 1}): robots {c.a} and {c.b}, centres {c.distance * 1e3:.1f} mm apart")
    return {"robot_radius_m": radius, "steps_added": result.steps_added(),
            "contacts": [{"step": c.step, "config": c.config + 1, "robots": [c.a, c.b], "distance_m": c.distance} for c in contacts]}


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
