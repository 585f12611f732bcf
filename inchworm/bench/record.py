"""MCAP recording throughput and its cost per coordination step (``swarm bench record``).

For each swarm size N (``sizes``) one realistic step's worth of encoded messages
is built once (robots on a jittered 0.25 m grid, 0.5 m sensing, half of them moving):
per moving robot a ``MotionCommand`` and two ``Status`` (accepted, done); per robot an
``ObserveRequest``, a ``TruthMessage`` and an ``ObservationReport`` of its neighbours, one ``TruthSetMessage``;
one ``EstimateMessage`` of all N robots; and one ``PlanMessage`` per configuration of
``steps_per_config`` steps. ``steps`` such steps are written through a fresh
``McapRecorder`` (zstd chunks, a file in a temporary folder), once with and once
without the derived Foxglove channels (``runtime.recording.foxglove_scene``), ``repeats`` times
each (median reported). The clock runs from the first ``write`` to the return of
``close()`` (queue drained, summary written), so it covers the whole cost of the file.

Reported per N and mode:

* ``msgs_per_s``, ``mb_per_s``: raw messages and raw payload megabytes (2^20 bytes)
  recorded per wall-clock second;
* ``cpu_us_per_msg``: process CPU time (all threads: the producer's ``write`` and the
  writer thread) per raw message;
* ``record_ms_per_step`` = ``cpu_us_per_msg`` x messages per step: the CPU a recorder
  spends on one step;
* ``overhead_pct`` = ``record_ms_per_step`` / ``step_ms`` (the measured coordination
  time of a step without recording, an input: e.g. the ``step_ms_median`` of ``swarm
  bench runtime``; one value for all sizes or one per size). The recorder is its own
  process (``swarm record``) and never delays a step: this is the CPU it takes from a
  machine that also runs the coordinator and the agents. Target: under 5 %.
"""

from __future__ import annotations

import math
import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from inchworm.bench import BenchResult
from inchworm.bench.options import RecordBenchOptions
from runtime.errors import OptionError
from runtime.recording.mcap_log import McapRecorder
from runtime.wire.messages import (
    EstimateMessage,
    Message,
    MotionCommand,
    ObservationReport,
    ObserveRequest,
    PlanMessage,
    Status,
    TruthMessage,
    TruthSetMessage,
    encode,
    message_key,
)

RUN = "bench-record"
SPACING_M = 0.25
SENSING_M = 0.5
TARGET_PCT = 5.0
MB = 2**20


def step_messages(n: int, step: int, rng: np.random.Generator, *, plan: bool) -> list[tuple[str, bytes]]:
    """Encoded ``(key, payload)`` of one inchworm step of ``n`` robots, in publishing order (every field built as
    the tuple its message declares)."""
    side = math.ceil(math.sqrt(n))
    grid = np.array([(i % side, i // side) for i in range(n)], float) * SPACING_M
    xy = grid + rng.normal(0.0, 0.02, (n, 2))
    heading = rng.uniform(-math.pi, math.pi, n)
    ids = tuple(range(n))
    half = max(1, n // 2)
    moving = ids[:half] if step % 2 else ids[n // 2:]
    poses = tuple((float(x), float(y), float(h)) for (x, y), h in zip(xy, heading, strict=True))
    msgs: list[Message] = []
    if plan:
        msgs.append(PlanMessage(run=RUN, step=step, config=1 + step // 4, n_anchors=n - len(moving),
                                groups=(ids[:half], ids[half:] or (n - 1,)) if n > 1 else ((0,),)))
    for r in moving:
        msgs.append(MotionCommand(run=RUN, step=step, robot=r, config=1, turn_rad=0.1, drive_m=0.12))
        msgs.append(Status(run=RUN, step=step, robot=r, state="accepted", reason=""))
        msgs.append(Status(run=RUN, step=step, robot=r, state="done", reason=""))
    msgs += [ObserveRequest(run=RUN, step=step, robot=r) for r in ids]
    d = np.linalg.norm(xy[:, None] - xy[None], axis=-1)
    for r in ids:
        msgs.append(TruthMessage(run=RUN, step=step, robot=r, pose=poses[r]))
        seen = tuple(j for j in ids if j != r and d[r, j] <= SENSING_M)
        bearings = tuple(float((math.atan2(xy[j, 1] - xy[r, 1], xy[j, 0] - xy[r, 0]) - heading[r] + math.pi) % (2 * math.pi) - math.pi)
                         for j in seen)
        msgs.append(ObservationReport(run=RUN, step=step, robot=r, observed=seen, ranges=tuple(float(d[r, j]) for j in seen),
                                      bearings=bearings))
    msgs.append(TruthSetMessage(run=RUN, step=step, ids=ids, poses=poses))
    cov = tuple(tuple(float(v) for v in row) for row in np.diag([1e-4, 1e-4, 1e-3]) + 1e-6)
    msgs.append(EstimateMessage(run=RUN, step=step, ids=ids, poses=poses, cov=(cov,) * n))
    return [(message_key(m), encode(m)) for m in msgs]


def record_once(messages: list[tuple[str, bytes]], trajectory: dict[str, Any], folder: Path, foxglove: bool) -> dict[str, float]:
    """Write ``messages`` through a fresh recorder; wall and CPU seconds from the first write to ``close()``."""
    path = folder / f"bench-{foxglove}.mcap"
    rec = McapRecorder(path, RUN, {"trajectory": trajectory}, foxglove=foxglove)
    cpu0, t0 = time.process_time(), time.perf_counter()
    for key, payload in messages:
        rec.write(key, payload)
    rec.close()
    wall, cpu = time.perf_counter() - t0, time.process_time() - cpu0
    out = {"wall_s": wall, "cpu_s": cpu, "bytes": path.stat().st_size, "derived": sum(rec.derived_counts().values())}
    path.unlink()
    return out


def bench_record(options: RecordBenchOptions | None = None, say: Callable[[str], None] | None = None) -> BenchResult:
    """Record ``steps`` steps of messages per size, with and without the derived channels (``options`` None: the
    defaults); ``say`` gets each table line."""
    args = options or RecordBenchOptions()
    sizes = list(args.sizes)
    step_ms = list(args.step_ms)
    if not sizes or min(sizes) < 1:
        raise OptionError("sizes", f"must list integers >= 1, got {args.sizes}", args)
    if len(step_ms) == 1:
        step_ms = step_ms * len(sizes)
    if len(step_ms) != len(sizes) or min(step_ms) <= 0:
        raise OptionError("step_ms", f": give one positive value or one per size ({len(sizes)}), got {','.join(map(str, args.step_ms))!r}", args)
    for name in ("steps", "steps_per_config", "repeats"):
        if getattr(args, name) < 1:
            raise OptionError(name, "must be at least 1", args)
    rng = np.random.default_rng(args.seed)
    results = []
    lines = [f"{'N':>4} {'derived':>7} {'msgs/step':>9} {'msgs/s':>8} {'MB/s':>6} {'us/msg':>7} {'ms/step':>8} "
          f"{'step ms':>7} {'overhead':>8}  derived msgs, file MB"]
    with tempfile.TemporaryDirectory(prefix="bench-record-") as tmp:
        for n, budget in zip(sizes, step_ms, strict=True):
            steps = [step_messages(n, s, rng, plan=(s - 1) % args.steps_per_config == 0) for s in range(1, args.steps + 1)]
            messages = [m for step in steps for m in step]
            payload_mb = sum(len(p) for _k, p in messages) / MB
            per_step = len(messages) / args.steps
            trajectory = {"robots": list(range(n)), "configurations": [[[0.1 * c + 0.25 * (i % 8), 0.25 * (i // 8)] for i in range(n)]
                                                                       for c in range(1 + args.steps // 4 + 1)]}
            for foxglove in (False, True):
                runs = [record_once(messages, trajectory, Path(tmp), foxglove) for _ in range(args.repeats)]
                wall = statistics.median(r["wall_s"] for r in runs)
                cpu = statistics.median(r["cpu_s"] for r in runs)
                us_per_msg = cpu / len(messages) * 1e6
                ms_per_step = us_per_msg * per_step / 1e3
                row = {"robots": n, "derived": foxglove, "msgs_per_step": round(per_step, 1),
                       "msgs_per_s": round(len(messages) / wall), "mb_per_s": round(payload_mb / wall, 2),
                       "cpu_us_per_msg": round(us_per_msg, 1), "record_ms_per_step": round(ms_per_step, 3),
                       "step_ms": budget, "overhead_pct": round(100 * ms_per_step / budget, 2),
                       "derived_msgs": runs[0]["derived"], "file_mb": round(runs[0]["bytes"] / MB, 3),
                       "payload_mb": round(payload_mb, 3)}
                results.append(row)
                lines.append(f"{n:>4} {'yes' if foxglove else 'no':>7} {per_step:>9.1f} {row['msgs_per_s']:>8} {row['mb_per_s']:>6.2f} "
                      f"{us_per_msg:>7.1f} {ms_per_step:>8.2f} {budget:>7g} {row['overhead_pct']:>7.1f}%  "
                      f"{row['derived_msgs']}, {row['file_mb']:.2f} (payload {payload_mb:.2f})")
                if say:
                    say(lines[-1])
    worst = max(r["overhead_pct"] for r in results)
    lines.append(f"worst overhead {worst:.1f} % of a step (target < {TARGET_PCT:g} %)")
    summary = {"results": results, "target_overhead_pct": TARGET_PCT, "steps": args.steps, "repeats": args.repeats}
    return BenchResult(results, summary, "\n".join(lines), "robots", "record_ms_per_step", "recorder CPU per step (ms)",
                       "MCAP recording: CPU per coordination step (with and without derived channels)")
