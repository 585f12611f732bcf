"""Wall time of one full anchor selection (outer + inner loop, Section 4.2) (``swarm bench select``).

For each swarm size a random start and desired configuration (one Section-7 step) are
drawn and ``AnchorSelector.select`` runs with the given budget (Monte Carlo samples,
genetic population and generations as in ``swarm sim``). ``one_core`` pins the process
to one core, as the targets are stated for one core. Each selection reports which counts
passed the outer-loop bound (``searched``) and where the genetic search ran (``genetic``);
``search_all`` lifts the bound (``prune_gain = 1``: every count searched) to time searched selections. Besides wall
time, the process's CPU time is reported (``cpu_s_*``: close to the wall time on an idle core, and
less sensitive to other processes' load).
"""

from __future__ import annotations

import math
import os
import statistics
import time
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from inchworm.bench import BenchResult
from inchworm.bench.options import SelectBenchOptions
from runtime.errors import OptionError
from runtime.models.state import SwarmEstimate
from runtime.models.trajectory import body_spacing, random_trajectory


def bench_select(options: SelectBenchOptions | None = None, say: Callable[[str], None] | None = None) -> BenchResult:
    """Time ``repeats`` selections per size (``options`` None: the defaults); ``say`` is told each selection as it starts."""
    from coordinator.localization import make_localizer  # noqa: PLC0415
    from coordinator.selection.selector import AnchorSelector  # noqa: PLC0415

    o = options or SelectBenchOptions()
    if o.repeats < 1:
        raise OptionError("repeats", f"must be >= 1, got {o.repeats}", o)
    if not o.sizes or min(o.sizes) < 2:
        raise OptionError("sizes", f"must list integers >= 2, got {o.sizes}", o)
    if o.one_core and hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    cfg = o.run.model
    localizer = make_localizer(o.run.localizer, cfg)
    selection = replace(o.run.selection, prune_gain=1.0) if o.search_all else o.run.selection
    results = []
    lines = [f"{'n':>5} {'s_median':>9} {'s_min':>7} {'s_max':>7} {'cpu_median':>10} {'cpu_max':>7} {'n_a chosen':>10} {'plans evaluated':>16} "
             f"{'searched':>8} {'s_max searched':>14}"]
    for n in o.sizes:
        times, cpu, chosen, evaluations, searched, genetic = [], [], [], [], [], []
        for r in range(o.repeats):
            if say:
                say(f"n={n} selection {r + 1}/{o.repeats}")
            traj = random_trajectory(n, 1, np.random.default_rng([o.seed, n, r]), sensing_range=cfg.sensing_range_m, **body_spacing(cfg))
            estimate = SwarmEstimate.isotropic(traj.ids, traj.initial_poses, 0.01, math.radians(2.0))
            selector = AnchorSelector(cfg, localizer, selection, seed=o.seed + r)
            t0, c0 = time.perf_counter(), time.process_time()
            sel = selector.select(estimate, traj.configurations[0])
            times.append(time.perf_counter() - t0)
            cpu.append(time.process_time() - c0)
            chosen.append(sel.n_anchors)
            evaluations.append(sel.evaluations)
            searched.append([s.n_anchors for s in sel.scores if s.searched])
            genetic.append([s.n_anchors for s in sel.scores if s.genetic])
        times_searched = [t for t, k in zip(times, searched, strict=True) if k]
        s_searched = round(max(times_searched), 4) if times_searched else None
        results.append({"n": n, "s_median": round(statistics.median(times), 4), "s_min": round(min(times), 4),
                        "s_max": round(max(times), 4), "n_a": chosen, "evaluations": evaluations, "s": [round(t, 4) for t in times],
                        "searched": searched, "genetic": genetic, "n_searched": len(times_searched), "s_max_searched": s_searched,
                        "cpu_s_median": round(statistics.median(cpu), 4), "cpu_s_max": round(max(cpu), 4)})
        lines.append(f"{n:>5} {statistics.median(times):>9.3f} {min(times):>7.3f} {max(times):>7.3f} {statistics.median(cpu):>10.3f} "
                     f"{max(cpu):>7.3f} {str(chosen):>10} {str(evaluations):>16} "
                     f"{len(times_searched):>8} {'-' if s_searched is None else f'{s_searched:.3f}':>14}")
    summary = {"results": results, "localizer": o.run.localizer, "one_core": o.one_core, "search_all": o.search_all,
               "genetic_gate": selection.genetic_gate}
    return BenchResult(results, summary, "\n".join(lines), "n", "s_median", "selection time, median (s)",
                       f"One anchor selection ({o.run.localizer} localizer{', one core' if o.one_core else ''})")
