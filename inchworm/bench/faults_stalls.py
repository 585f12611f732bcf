"""Rejoin and coordinator stalls for ``swarm bench faults`` (docs/failure-model.md), with real processes on loopback.

* ``rejoin``: per seed, a run of 6 agent processes and ``swarm coordinator`` (ref57, 5 configurations) at the default
  0.5 m sensing range; robot 2's agent is SIGKILLed when step 2 starts and restarted (same id, where its robot
  stands) once step 7 starts, the swarm having moved on; a run counts as ``rejoined`` when it exits 0 with robot 2
  rejoined and in the last step's estimate.
* ``coordinator_stall``: per seed, ``swarm launch -n 10 --standby --stall-coordinator STEP:12 --json``, STEP drawn
  among the run's steps (seeded): the coordinator is SIGSTOPped 12 s, beyond its 10 s session lease, so the standby
  takes the run over and the stalled one steps down when it resumes; ``completed`` counts runs that exit 0 with every
  configuration done and no robot lost.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import IO, Any

import msgspec
import numpy as np

from inchworm.output import last_json
from inchworm.processes import start_agents, stop_all
from inchworm.progress import Progress
from inchworm.spawn import Spawned, run_process
from inchworm.specs import AgentHostSpec, CoordinatorSpec, LaunchSpec
from runtime.models.config import ModelConfig
from runtime.models.trajectory import body_spacing, random_trajectory
from runtime.wire.keys import robot_wildcard, truth_key
from runtime.wire.messages import MessageError, MotionCommand, TruthMessage, decode
from runtime.wire.transport import free_tcp_port, loopback_hub, open_session, subscribe

STALL_S = 12.0  # s: beyond the 10 s Zenoh session lease
VICTIM, KILL_STEP, RESTART_STEP = 2, 2, 5


def _wait_step(steps: list[int], step: int, proc: subprocess.Popen[Any], timeout_s: float = 120.0) -> bool:
    """Until a command of ``step`` (or later) went out; False if ``proc`` ended first or the time ran out."""
    deadline = time.monotonic() + timeout_s
    while not any(s >= step for s in steps):
        if proc.poll() is not None or time.monotonic() > deadline:
            return False
        time.sleep(0.02)
    return True


def rejoin_run(seed: int, tmp: Path, log: int | IO[Any] = subprocess.DEVNULL) -> bool:
    """One run (module doc): whether robot ``VICTIM`` rejoined and finished the run with the others (``log``: where the
    coordinator's stderr goes)."""
    traj = random_trajectory(6, 6, np.random.default_rng(seed))
    traj_file = tmp / "traj.json"
    traj.save(traj_file)
    port = free_tcp_port()
    hub_settings, _ = loopback_hub(port)
    hub, run_id = f"tcp/127.0.0.1:{port}", f"rejoin-{seed}"
    steps: list[int] = []
    truth: dict[int, tuple[float, ...]] = {}
    procs: list[subprocess.Popen[Any]] = []

    def on_command(key: str, payload: bytes) -> None:
        try:
            steps.append(decode(payload, MotionCommand).step)
        except MessageError:
            pass

    with open_session(hub_settings) as session:
        subs = [subscribe(session, robot_wildcard(run_id, "cmd"), on_command),
                subscribe(session, truth_key(run_id, VICTIM), lambda key, payload: truth.update({0: decode(payload, TruthMessage).pose}))]
        try:
            agent = AgentHostSpec(run_id=run_id, robots=(), hub=hub, seed=seed, motion_time=0.3)
            agents = start_agents(traj, agent, procs, stderr=subprocess.DEVNULL)
            coordinator = Spawned(CoordinatorSpec(trajectory=str(traj_file), method="ref57", run_id=run_id, hub=hub, seed=seed, no_record=True,
                                                  out=str(tmp), result=str(tmp / "result.json")), stdout=subprocess.DEVNULL, stderr=log, cwd=tmp)
            procs.append(coordinator)
            if not _wait_step(steps, KILL_STEP, coordinator):
                return False
            agents[VICTIM].send_signal(signal.SIGKILL)
            agents[VICTIM].wait(timeout=10)
            if not _wait_step(steps, RESTART_STEP, coordinator):
                return False
            x, y, heading = truth[0]
            procs.append(Spawned(msgspec.structs.replace(agent, robots=(VICTIM,), run_robots=tuple(int(i) for i in traj.ids), pose=(x, y, heading)),
                                 stderr=subprocess.DEVNULL))
            coordinator.wait(timeout=300)
        finally:
            for sub in subs:
                sub.undeclare()
            stop_all(procs)
    if coordinator.returncode != 0 or not (tmp / "result.json").exists():
        return False
    result = json.loads((tmp / "result.json").read_text())
    return VICTIM in [r["robot"] for r in result["rejoined"]] and VICTIM in result["steps"][-1]["ids"]


def rejoin(runs: int) -> dict[str, float]:
    """``{"runs", "rejoined", "sensing_range_m"}`` over seeds 0..runs-1 (module doc)."""
    rejoined = 0
    progress = Progress(runs, "rejoin")
    for seed in range(runs):
        with tempfile.TemporaryDirectory(prefix="bench-faults-") as tmp:
            rejoined += rejoin_run(seed, Path(tmp))
        progress(seed + 1)
    return {"runs": runs, "rejoined": rejoined, "sensing_range_m": ModelConfig().sensing_range_m}


def coordinator_stall(runs: int, robots: int = 10, configs: int = 3, stall_s: float = STALL_S) -> dict[str, Any]:
    """``{"stall_s", "runs", "completed"}``: ``swarm launch --standby --stall-coordinator STEP:stall_s`` per seed."""
    from coordinator.simulate import simulate  # noqa: PLC0415

    completed = 0
    progress = Progress(runs, "coordinator stall")
    for seed in range(runs):
        traj = random_trajectory(robots, configs, np.random.default_rng(seed), **body_spacing(ModelConfig()))  # as launch draws it
        step = int(np.random.default_rng([seed, 43]).integers(1, len(simulate(traj, "inchworm", ModelConfig(), seed=seed).steps) + 1))
        with tempfile.TemporaryDirectory(prefix="bench-faults-") as tmp:
            proc = run_process(LaunchSpec(robots=robots, configs=configs, trajectory_seed=seed, seed=seed, standby=True,
                                          stall_coordinator=(step, stall_s), motion_time=0.1, no_record=True, out=tmp, json=True),
                               timeout=600, cwd=tmp)
        summary = last_json(proc.stdout) or {}
        completed += proc.returncode == 0 and len(summary.get("configs", [])) == configs and summary.get("lost") == []
        progress(seed + 1)
    return {"stall_s": stall_s, "runs": runs, "completed": completed}


if __name__ == "__main__":  # python -m inchworm.bench.faults_stalls [SEEDS]: both rows, one JSON line each
    seeds = int(sys.argv[1]) if len(sys.argv) > 1 else 10
    print(json.dumps({"rejoin": rejoin(seeds)}), flush=True)
    print(json.dumps({"coordinator_stall": coordinator_stall(seeds)}), flush=True)
