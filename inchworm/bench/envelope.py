"""Is the runtime correct away from its defaults? (``swarm bench envelope``; docs/benchmarks.md).

A matrix of operating points: motion noise x1, x3, x5.58 (turn 3, 9, 16.74 deg; drive 5, 15,
27.9 % of the distance; x5.58 is the calibrated noise of docs/experiments.md) x swarm sizes 10
and 30 x the paper's and the joint localizer x sensing ranges 0.5 m and 3 m, bodies on (the
model's default radius). Per operating point (a row):

* from ``trajectories`` in-process runs of ``inchworm`` (``configs`` configurations each, the
  trajectories of ``swarm compare``'s scheme): the position NEES / 2 after every configuration
  (``coordinator.consistency.position_nees``), its median ``nees_median`` and 95th percentile
  ``nees_p95`` (near 1: the covariances match the errors); contacts between bodies per 100
  configuration changes ``contacts_per_100``; the mean P_f (Eq. 24) ``pf_mean``; the steps per
  configuration ``steps_per_config`` and the coordinator's computing time per configuration in
  seconds ``s_per_config`` (selection and localization, in process);
* from one real distributed run (``swarm launch``: agent processes, a coordinator and a standby
  on a loopback Zenoh hub, recorded to MCAP) of ``distributed_configs`` configurations in which
  the coordinator is SIGKILLed at a step drawn at random and the standby takes the run over:
  ``takeover_identical``, the run's per-configuration table and P_f equal those of the
  in-process run of the same trajectory and seed (which an uninterrupted distributed run
  reproduces bit for bit), and ``replay_identical``, ``swarm replay --check`` reproduces every
  recorded estimate and plan of that recording exactly. ``None`` when ``distributed`` is off.

``to_json()`` (``swarm bench envelope --json``)::

    {"trajectories": T, "configs": C, "distributed_configs": D, "rows": [{"noise_scale", "robots",
     "localizer", "sensing_range_m", "replay_identical", "takeover_identical", "nees_median",
     "nees_p95", "contacts_per_100", "pf_mean", "s_per_config", "steps_per_config"}, ...]}
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, replace
from itertools import product
from pathlib import Path
from typing import Any

import numpy as np

from inchworm.bench import BenchResult
from inchworm.bench.options import EnvelopeBenchOptions
from inchworm.output import last_json
from inchworm.runner import pool_localizers, process_context, register_localizers
from inchworm.spawn import run_process
from inchworm.specs import LaunchSpec
from runtime.errors import SwarmInputError
from runtime.models.config import ModelConfig
from runtime.models.trajectory import Trajectory, body_spacing, random_trajectory

METHOD = "inchworm"


@dataclass(frozen=True)
class Point:
    """One operating point of the matrix."""

    noise_scale: float
    robots: int
    localizer: str
    sensing_range_m: float

    def model(self) -> ModelConfig:
        """The default model with the motion noise scaled and the sensing range set (bodies: the default radius)."""
        base = ModelConfig()
        return replace(base, turn_sigma_rad=base.turn_sigma_rad * self.noise_scale,
                       drive_sigma_frac=base.drive_sigma_frac * self.noise_scale, sensing_range_m=self.sensing_range_m)

    def trajectory(self, configs: int, seed: int) -> Trajectory:
        cfg = self.model()
        return random_trajectory(self.robots, configs, np.random.default_rng([seed, self.robots]), sensing_range=cfg.sensing_range_m,
                                 **body_spacing(cfg))


# -- in process -----------------------------------------------------------------------------------


def in_process_run(job: tuple[Point, int, int]) -> dict[str, Any]:
    """One in-process ``inchworm`` run of a point (trajectory seed ``seed``): NEES per configuration and the run's figures."""
    from coordinator.consistency import run_nees  # noqa: PLC0415
    from coordinator.simulate import simulate  # noqa: PLC0415

    point, configs, seed = job
    cfg = point.model()
    traj = point.trajectory(configs, seed)
    started = time.process_time()
    result = simulate(traj, METHOD, cfg, localizer=point.localizer, seed=seed)
    cpu = time.process_time() - started
    return {"nees": run_nees(result).tolist(), "contacts": len(result.contacts(cfg.robot_radius_m)), "configs": len(result.configs),
            "steps": int(result.steps_per_config().sum()), "pf": result.pf(), "cpu_s": cpu}


def in_process_figures(runs: list[dict[str, Any]]) -> dict[str, float]:
    """The row's in-process keys from its runs."""
    nees = np.concatenate([np.asarray(r["nees"], float) for r in runs])
    changes = sum(r["configs"] for r in runs)
    return {"nees_median": float(np.median(nees)), "nees_p95": float(np.percentile(nees, 95)),
            "contacts_per_100": 100.0 * sum(r["contacts"] for r in runs) / changes,
            "pf_mean": float(np.mean([r["pf"] for r in runs])), "s_per_config": sum(r["cpu_s"] for r in runs) / changes,
            "steps_per_config": sum(r["steps"] for r in runs) / changes}


# -- distributed ----------------------------------------------------------------------------------


def distributed_row(point: Point, configs: int, seed: int) -> dict[str, bool]:
    """A recorded ``swarm launch`` of the point whose coordinator is killed and taken over; replayed and compared."""
    from coordinator.simulate import simulate  # noqa: PLC0415
    from inchworm.bench.faults import same_table  # noqa: PLC0415
    from inchworm.replay import CheckOptions, check_recording  # noqa: PLC0415
    from runtime.models.model_file import model_toml  # noqa: PLC0415

    cfg = point.model()
    traj = point.trajectory(configs, seed)
    ref = simulate(traj, METHOD, cfg, localizer=point.localizer, seed=seed)
    kill_step = int(np.random.default_rng([seed, point.robots, 41]).integers(1, len(ref.steps) + 1))
    with tempfile.TemporaryDirectory(prefix="bench-envelope-") as tmp:
        folder = Path(tmp)
        traj.save(folder / "trajectory.json")
        (folder / "model.toml").write_text(model_toml(cfg))
        recording = folder / "run.mcap"
        proc = run_process(LaunchSpec(trajectory=str(folder / "trajectory.json"), model=cfg, model_file=str(folder / "model.toml"),
                                      localizer=point.localizer, method=METHOD, seed=seed, standby=True, kill_coordinator=kill_step,
                                      motion_time=0.1, record=str(recording), out=str(folder), json=True), timeout=900, cwd=tmp)
        summary = last_json(proc.stdout) or {}
        takeover = proc.returncode == 0 and same_table(summary, ref)
        replay = False
        if recording.exists():
            try:
                checked = check_recording(CheckOptions(recording)).result
                replay = checked.passed and checked.exact and checked.estimates > 0
            except SwarmInputError:
                replay = False
    return {"replay_identical": replay, "takeover_identical": takeover}


# -- the benchmark --------------------------------------------------------------------------------


def _in_process_rows(o: EnvelopeBenchOptions, points: list[Point], tick: Callable[[], None]) -> Iterator[dict[str, Any]]:
    jobs = [(p, o.configs, o.seed + t) for p in points for t in range(o.trajectories)]
    runs: list[dict[str, Any]] = []
    with ProcessPoolExecutor(max_workers=o.workers, mp_context=process_context(),
                             initializer=register_localizers, initargs=(pool_localizers(),)) as pool:
        for run in pool.map(in_process_run, jobs):
            runs.append(run)
            tick()
    for k, _point in enumerate(points):
        yield in_process_figures(runs[k * o.trajectories:(k + 1) * o.trajectories])


def operating_points(o: EnvelopeBenchOptions) -> list[Point]:
    """The operating points of the matrix, noise scale outermost."""
    return [Point(s, n, loc, r) for s, n, loc, r in product(o.noise_scales, o.robots, o.localizers, o.sensing_ranges_m)]


def bench_envelope(options: EnvelopeBenchOptions | None = None, say: Callable[[str], None] | None = None) -> BenchResult:
    """Every point of the matrix (module doc; ``options`` None: the defaults); ``say`` is told each stage and each
    finished row."""
    from inchworm.progress import Progress  # noqa: PLC0415

    o = options or EnvelopeBenchOptions()
    _say = say or (lambda _text: None)
    points = operating_points(o)
    _say(f"in process: {len(points)} points x {o.trajectories} runs of {o.configs} configurations ({METHOD}, bodies on)")
    progress, done = Progress(len(points) * o.trajectories, "bench envelope, in process"), [0]

    def tick() -> None:
        done[0] += 1
        progress(done[0])

    rows = [{"noise_scale": p.noise_scale, "robots": p.robots, "localizer": p.localizer, "sensing_range_m": p.sensing_range_m,
             "replay_identical": None, "takeover_identical": None, **figures}
            for p, figures in zip(points, _in_process_rows(o, points, tick), strict=True)]
    if o.distributed:
        _say(f"distributed: {len(points)} recorded runs of {o.distributed_configs} configurations, coordinator killed, "
             "standby takes over, replay --check")
        progress = Progress(len(points), "bench envelope, distributed")
        for k, (p, row) in enumerate(zip(points, rows, strict=True)):
            row.update(distributed_row(p, o.distributed_configs, o.seed))
            progress(k + 1)
            _say(_line(row))
    keys = ("noise_scale", "robots", "localizer", "sensing_range_m", "replay_identical", "takeover_identical", "nees_median",
            "nees_p95", "contacts_per_100", "pf_mean", "s_per_config", "steps_per_config")
    public = [{k: row[k] for k in keys} for row in rows]
    summary = {"trajectories": o.trajectories, "configs": o.configs, "distributed_configs": o.distributed_configs, "rows": public}
    header = (f"{'noise':>5} {'n_r':>4} {'localizer':<9} {'range m':>7} {'replay':>6} {'takeover':>8} {'NEES med':>8} {'p95':>6} "
              f"{'cont/100':>8} {'P_f':>7} {'s/config':>8} {'steps':>5}")
    lines = [f"{o.trajectories} in-process runs x {o.configs} configurations per row; distributed runs of {o.distributed_configs} "
             "configurations", header, *(_line(r) for r in public),
             "NEES: position NEES / 2 per configuration (1 = honest); s/config: coordinator CPU seconds per configuration, in process"]
    return BenchResult(public, summary, "\n".join(lines), "noise_scale", "nees_median", "position NEES / 2 (median)",
                       "the operating envelope")


def _line(r: dict[str, Any]) -> str:
    def flag(v: bool | None) -> str:
        return "-" if v is None else ("yes" if v else "NO")

    return (f"{r['noise_scale']:>5g} {r['robots']:>4} {r['localizer']:<9} {r['sensing_range_m']:>7g} {flag(r['replay_identical']):>6} "
            f"{flag(r['takeover_identical']):>8} {r['nees_median']:>8.2f} {r['nees_p95']:>6.2f} {r['contacts_per_100']:>8.2f} "
            f"{r['pf_mean']:>7.4f} {r['s_per_config']:>8.3f} {r['steps_per_config']:>5.2f}")
