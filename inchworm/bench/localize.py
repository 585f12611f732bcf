"""Time and accuracy of one localization step vs. the Cramer-Rao bound (``swarm bench localize``).

For each swarm size, ``trials`` random steps (``runtime.models.scenarios.random_step``,
grid spacing 0.25 m) are localized by the paper's method and by the joint least
squares; each call is timed ``repeats`` times. Accuracy is the RMS post-step
position error over robots and trials, compared with the RMS CRLB
(``coordinator.localization.crlb``, dead-reckoning prior + observations, at the
true poses). When GTSAM is importable (optional extra ``.[bench]``) the same
problem is solved as a GTSAM factor graph (Pose2 priors + BearingRange factors,
Levenberg-Marquardt) as an external reference for the joint solver.
"""

from __future__ import annotations

import math
import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from coordinator.localization.registry import BUILTIN_LOCALIZERS
from inchworm.bench import BenchResult
from inchworm.bench.options import LocalizeBenchOptions
from runtime.errors import OptionError
from runtime.models.config import ModelConfig

if TYPE_CHECKING:  # annotations only: the search and plotting are imported when a command runs
    from runtime.models.scenarios import StepCase


METHODS = BUILTIN_LOCALIZERS  # the built-in localizers: the keys of the JSON result
CRLB_LIMIT = 1000  # robots; the bound is a dense (3n x 3n) inverse
SPACING_M = 0.25
GAUSSIAN_FLOOR = 1e-12  # variance added to the GTSAM prior covariances (exact anchors)


def load_gtsam() -> Any | None:
    """The ``gtsam`` module, or None when the optional extra is not installed."""
    try:
        import gtsam  # noqa: PLC0415 - optional dependency
    except ImportError:
        return None
    return gtsam


def gtsam_localize(gtsam: Any, case: StepCase, cfg: ModelConfig, covariance: bool = False) -> Any:
    """Build and solve the joint problem of ``case`` as a GTSAM factor graph; returns the ``gtsam.Values``.

    Priors: the dead-reckoning mean and covariance. GTSAM's Pose2 tangent space is in
    the body frame, so the world-frame covariance is rotated by -heading on the xy block.
    ``covariance``: also the joint marginal covariance of all poses (``gtsam.Marginals``), the
    work our joint localizer does besides the solve (it returns the 3n x 3n joint covariance).
    """
    from coordinator.localization.dead_reckoning import dead_reckon  # noqa: PLC0415
    dr = dead_reckon(case.prior, case.step, cfg)
    i, j = case.observations.indexed(case.prior.ids)
    theta = dr.poses[:, 2]
    c, s = np.cos(theta), np.sin(theta)
    t = np.zeros((dr.n, 3, 3))
    t[:, 0, 0], t[:, 0, 1], t[:, 1, 0], t[:, 1, 1], t[:, 2, 2] = c, s, -s, c, 1.0
    cov_body = t @ dr.cov @ np.swapaxes(t, -1, -2) + GAUSSIAN_FLOOR * np.eye(3)

    graph = gtsam.NonlinearFactorGraph()
    initial = gtsam.Values()
    for k, (x, y, th) in enumerate(dr.poses.tolist()):
        pose = gtsam.Pose2(x, y, th)
        graph.add(gtsam.PriorFactorPose2(k, pose, gtsam.noiseModel.Gaussian.Covariance(cov_body[k])))
        initial.insert(k, pose)
    noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([cfg.bearing_sigma_rad, cfg.range_sigma_m]))
    obs = case.observations
    for a, b, rho, phi in zip(i.tolist(), j.tolist(), obs.range_m.tolist(), obs.bearing_rad.tolist(), strict=True):
        graph.add(gtsam.BearingRangeFactorPose2(a, b, gtsam.Rot2(phi), rho, noise))
    values = gtsam.LevenbergMarquardtOptimizer(graph, initial).optimize()
    if covariance:
        keys = gtsam.KeyVector(list(range(dr.n)))
        gtsam.Marginals(graph, values).jointMarginalCovariance(keys).fullMatrix()
    return values


def gtsam_positions(values: Any, n: int) -> np.ndarray:
    """Positions (n, 2) of keys 0..n-1."""
    out = np.empty((n, 2))
    for k in range(n):
        p = values.atPose2(k)
        out[k] = p.x(), p.y()
    return out


@dataclass
class MethodStats:
    """Timings (ms) and squared position errors (m^2) pooled over trials."""

    times_ms: list[float] = field(default_factory=list)
    sq_err: list[np.ndarray] = field(default_factory=list)

    def record(self, times_ms: list[float], positions: np.ndarray, truth: np.ndarray) -> None:
        self.times_ms.extend(times_ms)
        self.sq_err.append(np.sum((positions - truth) ** 2, axis=1))

    def summary(self, crlb_rms: float | None) -> dict[str, float | None]:
        err = float(np.sqrt(np.mean(np.concatenate(self.sq_err))))
        return {
            "ms_median": sig(statistics.median(self.times_ms)),
            "err_rms_m": sig(err),
            "err_over_crlb": sig(err / crlb_rms) if crlb_rms else None,
        }


def sig(x: float | None, digits: int = 4) -> float | None:
    """``x`` rounded to ``digits`` significant digits; None for None/NaN/inf."""
    if x is None or not math.isfinite(x):
        return None
    return float(f"{x:.{digits}g}")


def timed(fn: Any, repeats: int) -> tuple[list[float], Any]:
    """Wall times (ms) of ``repeats`` calls of ``fn()`` and the last result."""
    times, result = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        result = fn()
        times.append((time.perf_counter() - t0) * 1e3)
    return times, result


def bench_size(n: int, cfg: ModelConfig, args: LocalizeBenchOptions, gtsam: Any | None, say: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Result object of one swarm size."""
    from coordinator.localization import make_localizer  # noqa: PLC0415
    from coordinator.localization.crlb import crlb_pose_covariances  # noqa: PLC0415
    from coordinator.localization.dead_reckoning import dead_reckon  # noqa: PLC0415
    from coordinator.localization.joint import EXACT_COV_LIMIT  # noqa: PLC0415 - the joint covariance up to this n
    from runtime.models.scenarios import random_step  # noqa: PLC0415
    localizers = {name: make_localizer(name, cfg) for name in METHODS}
    stats = {name: MethodStats() for name in (*METHODS, "gtsam", "gtsam_cov")}
    crlb_sq: list[np.ndarray] = []
    n_obs: list[int] = []
    for trial in range(args.trials):
        if say:
            say(f"n={n} trial {trial + 1}/{args.trials}")
        case = random_step(n, cfg, np.random.default_rng(args.seed + trial), spacing=SPACING_M, seed=args.seed + trial,
                           still_delta=args.still_prior_m)
        truth = case.true_after[:, :2]
        n_obs.append(len(case.observations))
        for name, loc in localizers.items():
            times, est = timed(lambda loc=loc, case=case: loc.localize(case.prior, case.step, case.observations), args.repeats)
            stats[name].record(times, est.positions, truth)
        if n <= CRLB_LIMIT:
            dr = dead_reckon(case.prior, case.step, cfg)
            i, j = case.observations.indexed(case.prior.ids)
            cov = crlb_pose_covariances(case.true_after, dr.cov, i, j, cfg)
            crlb_sq.append(cov[:, 0, 0] + cov[:, 1, 1])
        if gtsam is not None:
            times, values = timed(lambda case=case: gtsam_localize(gtsam, case, cfg), args.repeats)
            stats["gtsam"].record(times, gtsam_positions(values, n), truth)
            if n <= EXACT_COV_LIMIT:
                times, values = timed(lambda case=case: gtsam_localize(gtsam, case, cfg, covariance=True), args.repeats)
                stats["gtsam_cov"].record(times, gtsam_positions(values, n), truth)

    crlb_rms = float(np.sqrt(np.mean(np.concatenate(crlb_sq)))) if crlb_sq else None
    per = {name: stats[name].summary(crlb_rms) for name in METHODS}
    result: dict[str, Any] = {
        "n": n,
        "ms_median": per["paper"]["ms_median"],
        "err_over_crlb": per["paper"]["err_over_crlb"],
        **per,
        "gtsam": stats["gtsam"].summary(crlb_rms) if gtsam is not None else None,
        "crlb_rms_m": sig(crlb_rms),
        "observations_mean": sig(float(np.mean(n_obs))),
    }
    if gtsam is not None:
        result["joint_over_gtsam_ms"] = sig(statistics.median(stats["joint"].times_ms) / statistics.median(stats["gtsam"].times_ms))
        result["joint_over_gtsam_time"] = result["joint_over_gtsam_ms"]  # the same ratio under a second key (part of the JSON contract)
        joint_err = float(np.sqrt(np.mean(np.concatenate(stats["joint"].sq_err))))
        gtsam_err = float(np.sqrt(np.mean(np.concatenate(stats["gtsam"].sq_err))))
        result["joint_over_gtsam_err"] = sig(joint_err / gtsam_err) if gtsam_err > 0 else None
        with_cov = stats["gtsam_cov"].times_ms
        result["gtsam_cov_ms_median"] = sig(statistics.median(with_cov)) if with_cov else None
        result["joint_over_gtsam_cov_time"] = (
            sig(statistics.median(stats["joint"].times_ms) / statistics.median(with_cov)) if with_cov else None
        )
    return result


def fmt(x: float | None, spec: str) -> str:
    return "-" if x is None else format(x, spec)


def table(results: list[dict[str, Any]], gtsam_used: bool) -> str:
    lines: list[str] = []
    header = f"{'n':>6}  {'method':<7} {'ms_median':>10} {'err_rms_m':>11} {'crlb_rms_m':>11} {'err/crlb':>9}"
    lines += [header, "-" * len(header)]
    for r in results:
        for name in (*METHODS, "gtsam"):
            m = r[name]
            if m is None:
                continue
            lines.append(
                f"{r['n']:>6}  {name:<7} {fmt(m['ms_median'], '10.3f')} {fmt(m['err_rms_m'], '11.5f')}"
                f" {fmt(r['crlb_rms_m'], '11.5f')} {fmt(m['err_over_crlb'], '9.3f')}"
            )
    if not gtsam_used:
        lines.append("\nGTSAM reference: skipped (--no-gtsam or gtsam not installed; pip install -e .[bench])")
        return "\n".join(lines)
    lines.append("\nGTSAM reference (same steps; joint / gtsam):")
    for r in results:
        lines.append(
            f"  n={r['n']}: time {fmt(r['joint']['ms_median'], '.3f')} ms"
            f" / {fmt(r['gtsam']['ms_median'], '.3f')} ms = {fmt(r['joint_over_gtsam_ms'], '.3g')}x,"
            f" error {fmt(r['joint']['err_rms_m'], '.5f')} m / {fmt(r['gtsam']['err_rms_m'], '.5f')} m"
            f" = {fmt(r['joint_over_gtsam_err'], '.4f')};"
            f" with GTSAM's joint marginal covariance too (the same work): {fmt(r['gtsam_cov_ms_median'], '.3f')} ms,"
            f" joint / that = {fmt(r['joint_over_gtsam_cov_time'], '.3g')}x"
        )
    return "\n".join(lines)


def bench_localize(options: LocalizeBenchOptions | None = None, say: Callable[[str], None] | None = None) -> BenchResult:
    """Time and accuracy per swarm size (``options`` None: the defaults); ``say`` is told each trial as it starts."""
    o = options or LocalizeBenchOptions()
    for name in ("trials", "repeats"):
        if getattr(o, name) < 1:
            raise OptionError(name, f"must be >= 1, got {getattr(o, name)}", o)
    if not o.sizes or min(o.sizes) < 2:
        raise OptionError("sizes", f"must list integers >= 2, got {o.sizes}", o)
    gtsam = load_gtsam() if o.gtsam else None
    results = [bench_size(n, o.model, o, gtsam, say) for n in o.sizes]
    from coordinator.localization.sparse_lm import sparse_backend  # noqa: PLC0415
    text = (f"swarm bench localize: {o.trials} trials x {o.repeats} repeats per size, seed {o.seed}, "
            f"sparse factorization {sparse_backend()}\n"
            "err = RMS post-step position error over robots and trials; crlb = RMS Cramer-Rao bound (n <= 1000)\n\n"
            + table(results, gtsam is not None))
    summary = {"results": results, "config": o.model.to_dict(), "seed": o.seed, "trials": o.trials, "repeats": o.repeats,
               "still_prior_m": o.still_prior_m, "sparse_backend": sparse_backend()}
    return BenchResult(results, summary, text, "n", "ms_median", "paper localizer, median time (ms)", "One localization step")
