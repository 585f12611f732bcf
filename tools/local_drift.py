"""Drift of the large-swarm localization around the movers over many configurations, against the whole swarm's solve
(docs/localization.md, "Large swarms: a step localized around its movers"; docs/benchmarks.md).

    PYTHONPATH=. python tools/local_drift.py --robots 300 --configs 15 --local-min 64 [--seed 0] [--method ref57] \
        [--motion-scale 1] [--max-fraction 0.25] [--json]

One simulated run, the paper's localizer solving the whole swarm at every step (``PaperLocalizer(local_min=huge)``)
drives the robots; beside it the localizer around the movers (``PaperLocalizer(local_min=...)``, the threshold
lowered so a mid-size swarm takes that path) localizes the same steps, the same commands and the same observations,
from its own estimate carried from step to step (``Paired``). The two estimates then differ only by the localizers,
never by the plan, the motion or the sensing noise. Per configuration, at its last step, of each estimate against the
truth: the mean and 99th percentile of the position errors (m), the mean position NEES (2 when the covariance is
honest), the mean heading error (rad). Prints one row per configuration and, last, one JSON object.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from coordinator.localization import movers, paper
from coordinator.localization.dead_reckoning import dead_reckon
from coordinator.localization.paper import PaperLocalizer
from coordinator.localization.superimpose import weighted_procrustes
from coordinator.run_result import RunResult
from coordinator.strategies import make_strategy
from inchworm.options import default_selection
from runtime.errors import LocalizationError
from runtime.models.config import ModelConfig
from runtime.models.geometry import rotate, wrap_angle
from runtime.models.state import Observations, StepCommands, SwarmEstimate

WHOLE_MIN = sys.maxsize  # ``local_min`` of the whole swarm's solve at every size


@dataclass
class Paired:
    """A localizer whose ``driver``'s estimates run the swarm while ``shadow`` localizes the same steps from its own
    estimate; ``shadows`` maps each estimate the driver returned (by ``id``) to the shadow's of the same step."""

    driver: PaperLocalizer
    shadow: PaperLocalizer
    name: str = "paired"
    shadows: dict[int, SwarmEstimate] = field(default_factory=dict)
    resyncs: int = 0  # steps whose prior was not the driver's last estimate (a fallback, a loss): the shadow restarted from it
    shadow_failures: int = 0  # steps the shadow could not localize (it kept its dead reckoning)
    region_steps: int = 0  # steps the shadow localized around their movers (the others: the whole swarm)
    steps: int = 0
    _last: SwarmEstimate | None = None
    _own: SwarmEstimate | None = None

    def topology(self, ids: np.ndarray, obs: Observations, initial_poses: np.ndarray | None = None) -> Any:
        return self.driver.topology(ids, obs, initial_poses)

    def localize(self, prior: SwarmEstimate, step: StepCommands, obs: Observations) -> SwarmEstimate:
        return self.localize_subset(prior, step, obs, np.ones(prior.n, bool))

    def localize_subset(self, prior: SwarmEstimate, step: StepCommands, obs: Observations, keep: np.ndarray) -> SwarmEstimate:
        out = self.driver.localize_subset(prior, step, obs, keep)
        own = self._own
        if self._last is None or own is None or not (
            np.array_equal(prior.ids, self._last.ids) and np.array_equal(prior.poses, self._last.poses)
        ):
            self.resyncs += self._last is not None
            own = prior
        try:
            mine = self.shadow.localize_subset(own, step, obs, keep)
        except LocalizationError:
            self.shadow_failures += 1
            mine = dead_reckon(own, step, self.shadow.cfg)
        self._last, self._own = out, mine
        self.steps += 1
        self.shadows[id(out)] = mine
        return out


def errors(estimate: SwarmEstimate, truth: np.ndarray) -> dict[str, float]:
    """Mean and 99th percentile position error (m), mean position NEES (2 if honest), mean heading error (rad), and
    the mean position error left once the estimate is turned and shifted onto the truth (``shape``, m: the error
    that is not the swarm's common drift)."""
    e = estimate.positions - truth[:, :2]
    dist = np.hypot(e[:, 0], e[:, 1])
    nees = np.einsum("ni,nij,nj->n", e, np.linalg.inv(estimate.cov[:, :2, :2]), e)
    theta, t, _ = weighted_procrustes(estimate.positions, truth[:, :2], np.ones(estimate.n))
    shape = rotate(theta, estimate.positions) + t - truth[:, :2]
    return {"mean": float(dist.mean()), "p99": float(np.percentile(dist, 99)), "nees": float(nees.mean()),
            "heading": float(np.abs(wrap_angle(estimate.poses[:, 2] - truth[:, 2])).mean()),
            "shape": float(np.hypot(shape[:, 0], shape[:, 1]).mean())}


def per_config(result: RunResult, paired: Paired) -> list[dict[str, Any]]:
    """One row per configuration: its last localized step's errors, whole (the driver) and local (the shadow)."""
    last: dict[int, Any] = {}
    for rec in result.steps:
        if id(rec.estimate) in paired.shadows and rec.truth is not None and rec.truth_ids is None:
            last[rec.config] = rec
    return [{"config": c, "step": rec.step, "whole": errors(rec.estimate, rec.truth),
             "local": errors(paired.shadows[id(rec.estimate)], rec.truth)} for c, rec in sorted(last.items())]


def run(robots: int, configs: int, local_min: int, seed: int, method: str, motion_scale: float,
        max_fraction: float = movers.LOCAL_MAX_FRACTION) -> tuple[list[dict[str, Any]], Paired, float]:
    """The paired run (module docstring): its rows, the ``Paired`` localizer (resyncs, failures) and the run's P_f (the
    whole solve's: it drove the robots); ``max_fraction``
    the largest region, as a share of the swarm, localized around its movers (``movers.LOCAL_MAX_FRACTION``: raised,
    a mid-size swarm takes that path as often as a large one)."""
    import inchworm  # noqa: PLC0415

    base = ModelConfig()
    cfg = replace(base, turn_sigma_rad=base.turn_sigma_rad * motion_scale, drive_sigma_frac=base.drive_sigma_frac * motion_scale)
    paired = Paired(PaperLocalizer(cfg, local_min=WHOLE_MIN), PaperLocalizer(cfg, local_min=local_min))
    traj = inchworm.SimOptions(robots=robots, configs=configs, seed=seed, model=cfg).run_trajectory()
    strategy = make_strategy(method, traj.n, cfg, paired.driver, default_selection(), seed)  # plans with the driver alone
    solved = paper.region_topology  # type: ignore[attr-defined]

    def counted(*args: Any, **kwargs: Any) -> Any:
        local = solved(*args, **kwargs)
        paired.region_steps += local is not None
        return local

    fraction = movers.LOCAL_MAX_FRACTION
    setattr(paper, "region_topology", counted)  # count the steps localized around their movers  # noqa: B010
    movers.LOCAL_MAX_FRACTION = max_fraction
    try:
        result = inchworm.simulate(traj, method=strategy, seed=seed, model=cfg, localizer=paired)
    finally:
        setattr(paper, "region_topology", solved)  # noqa: B010
        movers.LOCAL_MAX_FRACTION = fraction
    return per_config(result, paired), paired, float(result.pf())


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--robots", type=int, default=300)
    p.add_argument("--configs", type=int, default=15)
    p.add_argument("--local-min", type=int, default=64)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--method", default="ref57")
    p.add_argument("--motion-scale", type=float, default=1.0)
    p.add_argument("--max-fraction", type=float, default=movers.LOCAL_MAX_FRACTION)
    p.add_argument("--json", action="store_true")
    a = p.parse_args(argv)
    rows, paired, pf = run(a.robots, a.configs, a.local_min, a.seed, a.method, a.motion_scale, a.max_fraction)
    print(f"steps {paired.steps}, around the movers {paired.region_steps}, resyncs {paired.resyncs}, "
          f"shadow failures {paired.shadow_failures}, P_f {pf:.4f}")
    print("config step | mean mm whole local ratio | p99 mm whole local | NEES whole local | heading mrad whole local | shape mm whole local")
    for r in rows:
        w, lo = r["whole"], r["local"]
        print(f"{r['config']:6d} {r['step']:4d} | {1e3 * w['mean']:6.3f} {1e3 * lo['mean']:6.3f} {lo['mean'] / w['mean']:5.3f} | "
              f"{1e3 * w['p99']:6.2f} {1e3 * lo['p99']:6.2f} | {w['nees']:6.3f} {lo['nees']:6.3f} | "
              f"{1e3 * w['heading']:5.2f} {1e3 * lo['heading']:5.2f} | {1e3 * w['shape']:6.3f} {1e3 * lo['shape']:6.3f}")
    if a.json:
        print(json.dumps({"robots": a.robots, "configs": a.configs, "local_min": a.local_min, "seed": a.seed,
                          "method": a.method, "motion_scale": a.motion_scale,
                          "max_fraction": a.max_fraction, "steps": paired.steps,
                          "region_steps": paired.region_steps, "resyncs": paired.resyncs,
                          "shadow_failures": paired.shadow_failures, "pf": pf, "rows": rows}))


if __name__ == "__main__":
    main()
