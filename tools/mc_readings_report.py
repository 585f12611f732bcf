"""The pre-registered Monte Carlo readings (docs/experiments.md): a Markdown table from the cells of
``tools/mc_readings.sh`` (``OUT/<reading>-<localizer>-<noise>-<seed>/runs.csv``).

Per (reading, localizer, noise): each seed set's and the pooled mean P_f of inchworm and ref57, the ratio,
the two-sided paired t-test on the per-trajectory P_f (pooled over both seed sets), inchworm's mean n_a and
its mean n_a at configuration index 1..8, steps per configuration, drift (final e_l / distance travelled, %),
and whether the cell meets the pre-registered criterion of reproducing Table I.

Usage: python -m tools.mc_readings_report [OUT (default out/mc-readings)]
"""

from __future__ import annotations

import ast
import csv
import sys
from pathlib import Path

import numpy as np
from scipy import stats

READINGS = ("R0", "R1", "R2", "R3")
SEEDS = (0, 1000)
CONFIDENCE = 0.97


def load(path: Path) -> dict[str, list[dict]]:
    """Rows of one cell's runs.csv by method, sorted by trajectory."""
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    out: dict[str, list[dict]] = {}
    for r in rows:
        out.setdefault(r["method"], []).append(
            {"t": int(r["trajectory"]), "pf": float(r["pf"]), "na": float(r["n_a_mean"]), "steps": float(r["steps_mean"]),
             "drift": float(r["drift_pct"]), "along": ast.literal_eval(r["n_a_by_config"])})
    return {m: sorted(v, key=lambda r: r["t"]) for m, v in out.items()}


def ci(x: np.ndarray) -> tuple[float, float]:
    half = stats.t.ppf(0.5 + CONFIDENCE / 2, len(x) - 1) * x.std(ddof=1) / np.sqrt(len(x))
    return float(x.mean() - half), float(x.mean() + half)


def cell(out: Path, reading: str, loc: str, noise: str) -> dict | None:
    sets = {s: out / f"{reading}-{loc}-{noise}-{s}" / "runs.csv" for s in SEEDS}
    have = {s: load(p) for s, p in sets.items() if p.exists()}
    if not have:
        return None
    per_set = {s: float(np.mean([r["pf"] for r in d["inchworm"]]) / np.mean([r["pf"] for r in d["ref57"]])) for s, d in have.items()}
    inch = [r for d in have.values() for r in d["inchworm"]]
    ref = [r for d in have.values() for r in d["ref57"]]
    a, b = np.array([r["pf"] for r in inch]), np.array([r["pf"] for r in ref])
    p = float(stats.ttest_rel(a, b).pvalue)
    na = float(np.mean([r["na"] for r in inch]))
    along = np.mean([r["along"] for r in inch], axis=0)
    ratio = float(a.mean() / b.mean())
    meets = len(have) == 2 and 4 <= na <= 6 and ratio <= 0.8 and p < 0.03 and all(v < 1 for v in per_set.values())
    return {"seed_sets": sorted(have), "trajectories": len(a), "inchworm": (float(a.mean()), ci(a)), "ref57": (float(b.mean()), ci(b)),
            "per_set": per_set, "ratio": ratio, "p": p, "na": na, "along": [float(v) for v in along],
            "steps": float(np.mean([r["steps"] for r in inch])),
            "drift": (float(np.mean([r["drift"] for r in inch])), float(np.mean([r["drift"] for r in ref]))),
            "reproduces": meets}


def main(argv: list[str]) -> int:
    out = Path(argv[0]) if argv else Path("out/mc-readings")
    print("| reading | localizer | noise | seed sets (trajectories) | inchworm P_f [97 % CI] | ref57 P_f [97 % CI] "
          "| ratio per seed set | ratio pooled | p (paired) | n_a mean | n_a at configuration 1..8 | steps / config "
          "| drift % (inchworm, ref57) | Table I |")
    print("| --- | --- | --- | --- | --- | --- | --- | ---: | ---: | ---: | --- | ---: | --- | --- |")
    missing = []
    for noise in ("calibrated", "default"):
        for reading in READINGS:
            for loc in ("joint", "paper"):
                c = cell(out, reading, loc, noise)
                if c is None:
                    missing.append(f"{reading}-{loc}-{noise}")
                    continue
                (ai, (al, ah)), (bi, (bl, bh)) = c["inchworm"], c["ref57"]
                sets = ", ".join(f"{s}: {v:.3f}" for s, v in c["per_set"].items())
                print(f"| {reading} | {loc} | {noise} | {'+'.join(map(str, c['seed_sets']))} ({c['trajectories']}) "
                      f"| {ai:.4f} [{al:.4f}, {ah:.4f}] | {bi:.4f} [{bl:.4f}, {bh:.4f}] | {sets} | {c['ratio']:.3f} | {c['p']:.2g} "
                      f"| {c['na']:.2f} | {' '.join(f'{v:.1f}' for v in c['along'])} | {c['steps']:.2f} "
                      f"| {c['drift'][0]:.2f}, {c['drift'][1]:.2f} | {'reproduces' if c['reproduces'] else 'no'} |")
    if missing:
        print(f"\nnot run: {', '.join(missing)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
