"""Study throughput on every executor (``swarm bench studies``): the same small compare, 1 and 2 workers each.

Per executor (the local process pool and a Dask ``LocalCluster`` of single-threaded
processes) and number of workers W, the runs per second of one ``compare`` (wall time
from the first task submitted to the last row, cluster start-up and imports excluded),
and whether its rows equal those of the reference run (the local pool with one worker,
itself checked against Dask with one worker), the measured ``cpu_s`` left out. Parallel
efficiency = (runs/s with 2 workers) / (2 x runs/s with 1), the minimum over executors.
"""

from __future__ import annotations

import importlib
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from inchworm.bench import BenchResult
from inchworm.comparison import CompareOptions, compare
from inchworm.runner import EXECUTORS, Row, open_executor

MEASURED = ("cpu_s",)  # row keys that are measurements, not results


@dataclass(frozen=True)
class StudiesBenchOptions:
    compare: CompareOptions = field(default_factory=lambda: CompareOptions(robots=10, trajectories=8, configs=6, methods=("inchworm", "ref57")))
    workers: tuple[int, ...] = (1, 2)
    executors: tuple[str, ...] = EXECUTORS


def results_only(rows: list[Row]) -> list[Row]:
    """``rows`` without their measured CPU seconds: what must not depend on the executor."""
    return [{k: v for k, v in r.items() if k not in MEASURED} for r in rows]


def _timed_compare(kind: str, workers: int, options: CompareOptions) -> tuple[float, list[Row]]:
    with open_executor(kind, workers) as executor:
        client = getattr(executor, "client", None)
        if client is not None:
            client.run(importlib.import_module, "coordinator.simulate")  # every worker's imports before the clock
        t0 = time.perf_counter()
        result = compare(options, executor=executor)
        return time.perf_counter() - t0, result.rows


def bench_studies(options: StudiesBenchOptions = StudiesBenchOptions(), say: Callable[[str], None] | None = None) -> BenchResult:
    """Run the compare of ``options`` on every executor with each number of workers; ``say`` is told each as it starts."""
    o = options
    importlib.import_module("coordinator.simulate")  # the local pool forks this process: its imports before the clock
    runs = len(o.compare.tasks())
    measured: list[tuple[str, int, float, list[Row]]] = []
    for kind in o.executors:
        for w in o.workers:
            if say:
                say(f"{kind} executor, {w} worker{'s' * (w > 1)}: {runs} runs")
            wall, compared = _timed_compare(kind, w, o.compare)
            measured.append((kind, w, wall, results_only(compared)))
    reference = measured[0][3]
    check = next((m[3] for m in measured[1:] if m[0] != measured[0][0]), reference)
    rows: list[dict[str, Any]] = [{"executor": kind, "workers": w, "runs": runs, "runs_per_s": round(runs / wall, 4),
                                   "identical": (check if i == 0 else reference) == got}
                                  for i, (kind, w, wall, got) in enumerate(measured)]
    rate = {(r["executor"], r["workers"]): r["runs_per_s"] for r in rows}
    efficiency = [rate[(k, 2)] / (2 * rate[(k, 1)]) for k in o.executors if (k, 1) in rate and (k, 2) in rate]
    summary = {"rows": rows, "parallel_efficiency": round(min(efficiency), 4) if efficiency else None}
    load = " ".join(f"{x:.2f}" for x in os.getloadavg())
    lines = [f"{'executor':<9} {'workers':>7} {'runs':>5} {'runs/s':>8} identical",
             *(f"{r['executor']:<9} {r['workers']:>7} {r['runs']:>5} {r['runs_per_s']:>8.3f} {r['identical']}" for r in rows),
             f"parallel efficiency (minimum over executors): {summary['parallel_efficiency']}; load average {load} on {os.cpu_count()} cores"]
    return BenchResult(rows, summary, "\n".join(lines), "workers", "runs_per_s", "runs per second", "Study throughput per executor")
