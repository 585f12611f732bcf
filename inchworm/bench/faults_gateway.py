"""The gateway rows of the faults benchmark (``swarm bench faults``): whole ``swarm launch --driver gateway`` runs on a faulty radio.

For each seed, ``swarm launch --driver gateway --seed S --json`` runs twice as real
processes (emulated robots on ptys, one process per port with its link and gateway agents, coordinator): once
fault-free and once with the emulator's radio faults ``--drop P --corrupt P --delay S``
(each frame lost with probability ``drop`` in either direction, one byte of a robot's
answer flipped with probability ``corrupt``, every answer ``delay`` seconds late). A row
counts the faulty runs that completed (exit 0), those ``identical`` to the fault-free run
of the same seed (the same per-configuration table and P_f, compared exactly), and the
most times any robot executed a motion in any one step (``executed`` events of the
emulator's JSON-lines log, ``--emulator-events``): 1 means no retransmission ever moved a
robot twice. Fault-free runs are shared between rows (``baselines``).

Targets: every fault at 5 % together (drop 0.05, corrupt 0.05, delay 0.05 s):
10 of 10 seeds complete and identical, at most 1 execution per step; drop 0.2: at least
9 of 10 complete.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from collections import Counter
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

from inchworm.output import last_json
from inchworm.progress import Progress
from inchworm.spawn import run_process
from inchworm.specs import LaunchSpec

RUN_TIMEOUT_S = 300.0  # one whole launch (busy machine); a run that takes longer counts as not completed


def launch_gateway(seed: int, out: Path, drop: float = 0.0, corrupt: float = 0.0, delay: float = 0.0,
                   robots: int = 10, configs: int = 3) -> tuple[dict[str, Any] | None, int]:
    """One ``swarm launch --driver gateway`` run of ``robots`` robots and ``configs`` configurations
    (random trajectory of ``seed``) with these radio faults; (its ``--json`` summary or None if it
    failed, the most motions any robot executed in one step)."""
    out.mkdir(parents=True, exist_ok=True)
    events = out / "events.jsonl"
    spec = LaunchSpec(driver="gateway", robots=robots, configs=configs, trajectory_seed=seed, seed=seed, run_id=f"faults-{seed}", drop=drop,
                      corrupt=corrupt, delay=delay, emulator_events=str(events), out=str(out), no_record=True, json=True)
    try:
        proc = run_process(spec, timeout=RUN_TIMEOUT_S, cwd=out)
    except subprocess.TimeoutExpired:
        return None, executions_per_step(events)
    (out / "stderr.txt").write_text(proc.stderr)
    summary = last_json(proc.stdout) if proc.returncode == 0 else None
    return summary, executions_per_step(events)


def executions_per_step(events: Path) -> int:
    """The most ``executed`` events of one robot in one step of an emulator event log (0 if none)."""
    if not events.exists():
        return 0
    counts: Counter[tuple[int, int]] = Counter()
    for line in events.read_text().splitlines():
        try:
            row = json.loads(line)
        except json.JSONDecodeError:
            continue  # a line cut by the emulator's stop
        if row.get("event") == "executed":
            counts[(row["robot"], row["step"])] += 1
    return max(counts.values(), default=0)


def same_result(a: dict[str, Any] | None, b: dict[str, Any] | None) -> bool:
    """Whether two ``--json`` summaries have the same per-configuration table and P_f (exactly)."""
    return a is not None and b is not None and a["configs"] == b["configs"] and a["pf"] == b["pf"]


def gateway_fault_row(drop: float, corrupt: float, delay: float, seeds: Iterable[int], baselines: dict[int, dict[str, Any] | None] | None = None,
                      robots: int = 10, configs: int = 3, workdir: Path | None = None,
                      progress: Callable[[int], None] | None = None) -> dict[str, float]:
    """``{"drop", "corrupt", "delay", "runs", "completed", "identical", "max_executions_per_step"}`` over ``seeds``.

    ``baselines`` (seed -> fault-free summary) is filled with the fault-free runs it makes, so
    several rows share them; ``progress(k)`` is called after each seed.
    """
    seeds = list(seeds)
    baselines = {} if baselines is None else baselines
    completed = identical = max_exec = 0
    with tempfile.TemporaryDirectory(prefix="swarm-bench-faults-") as tmp:
        root = Path(workdir or tmp)
        tag = f"drop{drop:g}-corrupt{corrupt:g}-delay{delay:g}"
        for k, seed in enumerate(seeds, 1):
            if seed not in baselines:
                baselines[seed], _ = launch_gateway(seed, root / f"clean-{seed}", robots=robots, configs=configs)
            result, executions = launch_gateway(seed, root / f"{tag}-{seed}", drop, corrupt, delay, robots, configs)
            completed += result is not None
            identical += same_result(result, baselines[seed])
            max_exec = max(max_exec, executions)
            if progress is not None:
                progress(k)
    return {"drop": drop, "corrupt": corrupt, "delay": delay, "runs": len(seeds), "completed": completed,
            "identical": identical, "max_executions_per_step": max_exec}


DEFAULT_ROWS = ((0.05, 0.05, 0.05), (0.2, 0.0, 0.0))


def gateway_fault_rows(rows: Iterable[tuple[float, float, float]] = DEFAULT_ROWS, seeds: Iterable[int] = range(10),
                       robots: int = 10, configs: int = 3, show_progress: bool = True) -> list[dict[str, float]]:
    """``gateway_fault_row`` of each (drop, corrupt, delay) in ``rows``, sharing the fault-free runs."""
    rows, seeds = list(rows), list(seeds)
    baselines: dict[int, dict[str, Any] | None] = {}
    bar = Progress(len(rows) * len(seeds), "bench faults (gateway)", show_progress)
    out = []
    for i, (drop, corrupt, delay) in enumerate(rows):
        def progress(k: int, done: int = i * len(seeds)) -> None:
            bar(done + k)

        out.append(gateway_fault_row(drop, corrupt, delay, seeds, baselines, robots, configs, progress=progress))
    return out


if __name__ == "__main__":  # python -m swarm_cli.bench_faults_gateway [SEEDS]: the default rows, one JSON line
    print(json.dumps(gateway_fault_rows(seeds=range(int(sys.argv[1]) if len(sys.argv) > 1 else 10))))
