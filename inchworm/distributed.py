"""A distributed run from Python: a loopback Zenoh hub, one agent process per robot, the coordinator in this process.

The same run as ``swarm launch`` (agents as real processes speaking the wire protocol,
the coordinator's executor over Zenoh), without the launcher's command line: it returns the
``RunResult``, which equals the in-process ``simulate`` of the same trajectory, method and
seed bit for bit (docs/protocol.md). Every process started is stopped by its pid at the end.
"""

from __future__ import annotations

import subprocess
import tempfile
import uuid
from pathlib import Path
from typing import TYPE_CHECKING

from inchworm.simulation import resolve_trajectory
from runtime.models.config import ModelConfig
from runtime.paths import StrPath, as_path

if TYPE_CHECKING:
    from coordinator.run_result import RunResult
    from coordinator.selection.selector import SelectionConfig
    from runtime.models.trajectory import Trajectory


def run_distributed(
    trajectory: Trajectory | StrPath | None = None,
    *,
    method: str = "inchworm",
    robots: int = 10,
    configs: int = 3,
    seed: int = 0,
    model: ModelConfig | None = None,
    localizer: str = "paper",
    selection: SelectionConfig | None = None,
    record: StrPath | None = None,
    agents_per_process: int | None = None,
    start_timeout_s: float | None = None,
    step_timeout_s: float = 5.0,
) -> RunResult:
    """Run ``method`` along ``trajectory`` (as ``simulate`` takes it) with one agent process per robot (or
    ``agents_per_process``); ``record``: an MCAP file of every message. Raises a ``SwarmRunError``
    (``AgentLost``, ``RunAborted``, ...) when the agents do not come up or the run is aborted."""
    from coordinator.node.process import CoordinatorOptions, run_coordinator  # noqa: PLC0415
    from coordinator.node.stop import StopSignals  # noqa: PLC0415
    from inchworm.launcher import check_writable  # noqa: PLC0415
    from inchworm.processes import agents_per_process as per_process_for, start_agents, stop_all  # noqa: PLC0415
    from inchworm.specs import AgentHostSpec  # noqa: PLC0415
    from runtime.wire.transport import open_loopback_hub  # noqa: PLC0415

    cfg = model or ModelConfig()
    traj = resolve_trajectory(trajectory, robots, configs, seed, cfg)
    if record is not None:
        check_writable(as_path(record).parent, "record", record)
    run_id = f"api-{uuid.uuid4().hex[:8]}"
    procs: list[subprocess.Popen[bytes]] = []
    signals = StopSignals()
    try:
        hub_session, member, hub = open_loopback_hub()
        with hub_session, tempfile.TemporaryDirectory(prefix="inchworm-run-") as tmp:
            traj_file = Path(tmp) / "trajectory.json"
            traj.save(traj_file)
            start_agents(traj, AgentHostSpec(run_id=run_id, robots=(), hub=hub, seed=seed, model=cfg), procs,
                         per_process_for(traj.n, agents_per_process), traj_file, stdout=subprocess.DEVNULL)
            options = CoordinatorOptions(traj, run_id, member, hub, method, seed, localizer, cfg, None, selection,
                                         start_timeout_s or max(30.0, 0.1 * traj.n), step_timeout_s, record=as_path(record),
                                         command="inchworm.run_distributed")
            outcome = run_coordinator(options, signals, log=lambda _line: None)
    finally:
        signals.restore()
        stop_all(procs)
    if outcome.error is not None:
        raise outcome.error
    assert outcome.result is not None  # no error: a result
    return outcome.result


__all__ = ["run_distributed"]
