"""Where the genetic search beats its heuristic seed (``swarm study selection --genetic-gain``).

For ``configs`` random steps of ``robots`` robots (drawn as ``swarm bench select`` draws them:
``random_trajectory`` with the seed [seed, robots, c], start estimate 0.01 m / 2 deg), every
anchor count the selection screens (n_a > 0, at most ``max_steps`` steps) is searched with the
genetic search forced on (``genetic_gate = "on"``, every count searched: ``prune_gain = 1``).
The plan it keeps (after the race and the final check) and its seed (the heuristic plan of
Eq. 11-13, repaired for bodies; a count without one, or without any connected plan found, counts as
"no seed") are then evaluated on ``eval_samples`` fresh samples
(``samples_for``-scaled, common random numbers): the paired per-sample difference says whether
the search beat its seed by more than ``BEYOND_NOISE`` standard errors (the Monte Carlo's
noise), lost by as much, or neither. The seconds the forced search took are recorded too.
``coordinator.selection.selector.genetic_pays`` is set from these measurements (docs/selection.md).
"""

from __future__ import annotations

import math
import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from inchworm.options import RunOptions, check_at_least

BEYOND_NOISE = 2.0  # standard errors of the paired difference on the evaluation samples
# fresh samples each kept plan and its seed are evaluated on, for 10 robots (scaled by 10 / n_r like the selection's,
# ``samples_for``): what docs/selection.md's grid (tools/genetic_gain.sh, docs/data/genetic-gain/) was measured with;
# not the selection study's evaluation set (``SelectionStudyOptions.eval_samples``)
EVAL_SAMPLES = 256


@dataclass(frozen=True, kw_only=True)
class GeneticGainOptions:
    robots: int = 10
    configs: int = 8
    eval_samples: int = EVAL_SAMPLES
    seed: int = 0
    run: RunOptions = field(default_factory=RunOptions)

    def __post_init__(self) -> None:
        check_at_least(self, "robots", 3)
        check_at_least(self, "configs", 1)
        check_at_least(self, "eval_samples", 2)


@dataclass
class GeneticGainResult:
    """One row per (configuration, anchor count): e_l (m) of the seed and the kept plan on the evaluation samples."""

    options: GeneticGainOptions
    rows: list[dict[str, Any]]

    def counts(self) -> dict[str, dict[str, Any]]:
        out: dict[str, dict[str, Any]] = {}
        for n_a in sorted({r["n_a"] for r in self.rows}):
            rows = [r for r in self.rows if r["n_a"] == n_a]
            have = [r for r in rows if r["seed_e_l"] is not None]
            gains = [100.0 * r["gain"] / r["seed_e_l"] for r in have]
            out[str(n_a)] = {"cases": len(rows), "no_seed": len(rows) - len(have),
                             "replaced": sum(r["replaced"] for r in have), "beats": sum(r["beats"] for r in have),
                             "loses": sum(r["loses"] for r in have),
                             "gain_pct_median": round(statistics.median(gains), 3) if gains else None,
                             "gain_pct_max": round(max(gains), 3) if gains else None,
                             "search_s_median": round(statistics.median(r["search_s"] for r in rows), 3)}
        return out

    def to_json(self) -> dict[str, Any]:
        o, counts = self.options, self.counts()
        return {"robots": o.robots, "configs": o.configs, "localizer": o.run.localizer,
                "turn_sigma_deg": round(math.degrees(o.run.model.turn_sigma_rad), 6), "drive_sigma_frac": o.run.model.drive_sigma_frac,
                "robot_radius_m": o.run.model.robot_radius_m, "eval_samples": o.eval_samples, "counts": counts,
                "cases": sum(c["cases"] for c in counts.values()), "beats": sum(c["beats"] for c in counts.values()),
                "loses": sum(c["loses"] for c in counts.values())}

    def report(self) -> str:
        j = self.to_json()
        lines = [f"genetic search against its seed: n_r = {j['robots']}, {j['configs']} configurations, localizer {j['localizer']}, "
                 f"turn {j['turn_sigma_deg']:g} deg, drive {j['drive_sigma_frac']:g}, radius {j['robot_radius_m']:g} m; "
                 f"beats/loses = by more than {BEYOND_NOISE:g} standard errors on fresh samples",
                 f"{'n_a':>5} {'cases':>5} {'no seed':>7} {'replaced':>8} {'beats':>5} {'loses':>5} {'gain % med':>10} {'max':>7} {'search s':>8}"]
        for n_a, c in j["counts"].items():
            med = "-" if c["gain_pct_median"] is None else f"{c['gain_pct_median']:.2f}"
            top = "-" if c["gain_pct_max"] is None else f"{c['gain_pct_max']:.2f}"
            lines.append(f"{n_a:>5} {c['cases']:>5} {c['no_seed']:>7} {c['replaced']:>8} {c['beats']:>5} {c['loses']:>5} {med:>10} {top:>7} "
                         f"{c['search_s_median']:>8.3f}")
        lines.append(f"beats its seed in {j['beats']} of {j['cases']}, loses in {j['loses']}")
        return "\n".join(lines)


def gain_rows(options: GeneticGainOptions, config: int) -> list[dict[str, Any]]:
    """The rows of configuration ``config``: one per screened anchor count n_a > 0."""
    from coordinator.localization import make_localizer  # noqa: PLC0415 - the search loads when a study runs
    from coordinator.selection.monte_carlo import MonteCarlo  # noqa: PLC0415
    from coordinator.selection.selector import AnchorSelector, NoFeasiblePlanError, samples_for  # noqa: PLC0415
    from runtime.models.state import SwarmEstimate  # noqa: PLC0415
    from runtime.models.trajectory import body_spacing, random_trajectory  # noqa: PLC0415

    o, n = options, options.robots
    cfg = o.run.model
    localizer = make_localizer(o.run.localizer, cfg)
    traj = random_trajectory(n, 1, np.random.default_rng([o.seed, n, config]), sensing_range=cfg.sensing_range_m, **body_spacing(cfg))
    estimate = SwarmEstimate.isotropic(traj.ids, traj.initial_poses, 0.01, math.radians(2.0))
    desired = traj.configurations[0]
    fresh = MonteCarlo(cfg, localizer, samples_for(o.eval_samples, n), int(np.random.default_rng([o.seed, n, config, 1]).integers(2**63)),
                       o.run.selection.mc_start)
    rows = []
    for n_a in (k for k in AnchorSelector(cfg, localizer, o.run.selection, 0).candidate_counts(n) if k > 0):
        forced = replace(o.run.selection, anchor_counts=(n_a,), genetic_gate="on", prune_gain=1.0)
        t0 = time.perf_counter()
        try:
            entry = AnchorSelector(cfg, localizer, forced, seed=config).select(estimate, desired).scores[0]
        except NoFeasiblePlanError:  # no connected plan of this count found: nothing to compare
            entry = None
        row: dict[str, Any] = {"config": config, "n_a": n_a, "search_s": round(time.perf_counter() - t0, 4), "seed_e_l": None,
                               "gain": 0.0, "gain_se": 0.0, "replaced": 0, "beats": 0, "loses": 0}
        if entry is not None and entry.seed is not None and entry.plan is not None:
            each = fresh.localization_errors(estimate, desired, [entry.seed, entry.plan], per_sample=True)
            diff = each[0] - each[1]  # > 0: the kept plan is better
            se = float(diff.std(ddof=1) / np.sqrt(len(diff)))
            gain = float(diff.mean())
            row.update(seed_e_l=float(each[0].mean()), gain=gain, gain_se=se, replaced=int(entry.plan.key() != entry.seed.key()),
                       beats=int(gain > BEYOND_NOISE * se > 0), loses=int(-gain > BEYOND_NOISE * se > 0))
        rows.append(row)
    return rows


def study_genetic_gain(options: GeneticGainOptions, say: Callable[[str], None] | None = None) -> GeneticGainResult:
    """Every configuration's rows (serial; ``say`` is told each configuration as it starts)."""
    rows = []
    for c in range(options.configs):
        if say:
            say(f"genetic gain: configuration {c + 1}/{options.configs}")
        rows += gain_rows(options, c)
    return GeneticGainResult(options, rows)
