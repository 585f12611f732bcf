"""Re-run the pre-registered reading R1 (docs/experiments.md) at full size with the current code.

R1: ``--mc-start known --mc-emax mean``, the joint localizer, the calibrated motion noise (x 5.58: turn 16.74 deg,
drive 27.9 %), n_r = 10, 30 trajectories x 8 configurations per seed set, ``inchworm`` against ``ref57`` on the same
trajectories. Seed sets 0 and 1000 (the registered ones) and 2000 and 3000 (new), each point robots
(``--robot-radius 0``, as registered) and with bodies (the default radius). One ``swarm compare`` per cell; its
per-trajectory rows stay in ``OUT/<cell>/runs.csv`` and a finished cell is not run again (an interrupted re-run
goes on where it stopped).

Per (bodies, seed sets) the report gives the mean P_f of both methods, the ratio of the means, the paired
per-trajectory ratio inchworm / ref57 as a geometric mean with its 95 % confidence interval (t on the log ratios),
the two-sided paired t-test on P_f, and inchworm's mean n_a.

``--recalibrated`` runs the same cells at the noise the calibration gives with the exact dead reckoning instead
(docs/experiments.md, "The calibration of the noise"): x 6.93 for point robots, x 7.12 with bodies.

Usage: python -m tools.r1_rerun [OUT (default out/r1-rerun)] [WORKERS (default 2)] [--recalibrated] [--report-only]
Prints a Markdown table; ``--json`` as the last argument also prints its rows as one JSON object (last line).
"""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
from scipy import stats

SEED_SETS = (0, 1000, 2000, 3000)
R1 = ["--mc-start", "known", "--mc-emax", "mean", "--localizer", "joint"]
TURN_X1_DEG, DRIVE_X1 = 3.0, 0.05  # motion noise x 1
FIRST_SCALE = 5.58  # the calibration as first measured (registered)
RECALIBRATED = {False: 6.93, True: 7.12}  # the calibration with the exact dead reckoning: points, bodies


def noise_flags(scale: float) -> list[str]:
    """The motion-noise flags of ``scale`` x the default (x 5.58: turn 16.74 deg, drive 27.9 %)."""
    return ["--turn-sigma-deg", f"{TURN_X1_DEG * scale:.6g}", "--drive-sigma-frac", f"{DRIVE_X1 * scale:.6g}"]


def cell_name(seed: int, bodies: bool, recalibrated: bool = False) -> str:
    scale = f"-x{RECALIBRATED[bodies]}" if recalibrated else ""
    return f"R1-joint-calibrated{scale}-{'bodies' if bodies else 'points'}-{seed}"


def run_cell(out: Path, seed: int, bodies: bool, workers: int, recalibrated: bool = False) -> None:
    folder = out / cell_name(seed, bodies, recalibrated)
    if (folder / "done").exists():
        return
    cmd = [sys.executable, "-m", "swarm_cli.main", "compare", "--trajectories", "30", "--configs", "8", "--robots", "10",
           "--methods", "inchworm,ref57", "--seed", str(seed), *R1,
           *noise_flags(RECALIBRATED[bodies] if recalibrated else FIRST_SCALE), *([] if bodies else ["--robot-radius", "0"]),
           "--workers", str(workers), "--out", str(folder), "--json"]
    if folder.exists():
        cmd.append("--resume")
    print(f"r1: {' '.join(cmd[3:])}", file=sys.stderr, flush=True)
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    (folder / "done").write_text("")


def load(folder: Path) -> dict[str, dict[int, dict]]:
    with open(folder / "runs.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    out: dict[str, dict[int, dict]] = {}
    for r in rows:
        out.setdefault(r["method"], {})[int(r["trajectory"])] = {"pf": float(r["pf"]), "na": float(r["n_a_mean"])}
    return out


def summary(out: Path, seeds: tuple[int, ...], bodies: bool, recalibrated: bool = False) -> dict:
    """The paired comparison pooled over the seed sets ``seeds``."""
    ours, theirs, na = [], [], []
    for seed in seeds:
        runs = load(out / cell_name(seed, bodies, recalibrated))
        common = sorted(set(runs["inchworm"]) & set(runs["ref57"]))
        ours += [runs["inchworm"][t]["pf"] for t in common]
        theirs += [runs["ref57"][t]["pf"] for t in common]
        na += [runs["inchworm"][t]["na"] for t in common]
    a, b = np.array(ours), np.array(theirs)
    logs = np.log(a / b)
    half = stats.t.ppf(0.975, len(logs) - 1) * logs.std(ddof=1) / np.sqrt(len(logs))
    return {"bodies": bodies, "seeds": list(seeds), "pairs": len(a), "pf_inchworm": float(a.mean()), "pf_ref57": float(b.mean()),
            "ratio_of_means": float(a.mean() / b.mean()), "paired_ratio": float(np.exp(logs.mean())),
            "paired_ratio_ci95": [float(np.exp(logs.mean() - half)), float(np.exp(logs.mean() + half))],
            "p_paired_t": float(stats.ttest_rel(a, b).pvalue), "na_inchworm": float(np.mean(na))}


def main(argv: list[str]) -> int:
    as_json = "--json" in argv
    report_only = "--report-only" in argv
    recalibrated = "--recalibrated" in argv
    args = [a for a in argv if not a.startswith("--")]
    out = Path(args[0]) if args else Path("out/r1-rerun")
    workers = int(args[1]) if len(args) > 1 else 2
    if not report_only:
        for bodies in (False, True):
            for seed in SEED_SETS:
                run_cell(out, seed, bodies, workers, recalibrated)
    rows = [summary(out, seeds, bodies, recalibrated) for bodies in (False, True)
            for seeds in ((0,), (1000,), (0, 1000), (2000,), (3000,), (2000, 3000), SEED_SETS)]
    print("| robots | seed sets | pairs | P_f inchworm | P_f ref57 | ratio of means | paired ratio [95 % CI] | p (paired t) | n_a |")
    print("| --- | --- | ---: | ---: | ---: | ---: | --- | ---: | ---: |")
    for r in rows:
        lo, hi = r["paired_ratio_ci95"]
        print(f"| {'bodies' if r['bodies'] else 'points'} | {'+'.join(map(str, r['seeds']))} | {r['pairs']} | {r['pf_inchworm']:.4f} | "
              f"{r['pf_ref57']:.4f} | {r['ratio_of_means']:.3f} | {r['paired_ratio']:.3f} [{lo:.3f}, {hi:.3f}] | {r['p_paired_t']:.2g} | "
              f"{r['na_inchworm']:.2f} |")
    if as_json:
        print(json.dumps({"rows": rows}))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
