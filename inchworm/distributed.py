"""A distributed run from Python: a loopback Zenoh hub, one agent process per robot, the coordinator in this process.

The same run as ``swarm launch`` (agents as real processes speaking the wire protocol,
the coordinator's executor over Zenoh), without the launcher's command line: its
``RunResult`` equals the in-process ``simulate`` of the same trajectory, method and
seed bit for bit (docs/protocol.md). Every process started is stopped by its pid at the end.

``DistributedRun`` is that run as an object with a lifecycle, as ``inchworm.Swarm`` is for a launched run:

    with inchworm.DistributedRun(trajectory, method="inchworm", seed=0) as run:   # the hub and the agents start
        run.status().agents          # robots whose agents are alive (their liveliness tokens on the run's hub)
        result = run.wait()          # the coordinator runs here (main thread: its stop signals) -> RunResult
    run.result()                     # the same RunResult once it ended

``estop(reason)`` (from another thread while ``wait`` runs, or before it) sends the run-wide emergency stop as
``swarm estop --run`` does; leaving the ``with`` block stops every agent process and closes the hub.
``run_distributed(...)`` is ``DistributedRun(...).wait()`` with everything stopped afterwards.
"""

from __future__ import annotations

import contextlib
import os
import subprocess
import tempfile
import uuid
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any

from inchworm.sim_options import resolve_trajectory
from runtime.errors import SwarmInputError
from runtime.models.config import ModelConfig
from runtime.paths import StrPath, as_path

if TYPE_CHECKING:
    from coordinator.node.stop import EstopOutcome
    from coordinator.run_result import RunResult
    from coordinator.selection.selector import SelectionConfig
    from inchworm.swarm import SwarmStatus
    from runtime.models.trajectory import Trajectory


class DistributedRun:
    """A distributed run (module doc): ``trajectory`` as ``simulate`` takes it (or ``robots`` x ``configs`` drawn with
    ``seed``), one agent process per robot (or ``agents_per_process``); ``record``: an MCAP file of every message."""

    def __init__(
        self,
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
    ) -> None:
        from inchworm.launcher import check_writable  # noqa: PLC0415

        self.model = model or ModelConfig()
        self.trajectory = resolve_trajectory(trajectory, robots, configs, seed, self.model)
        if record is not None:
            check_writable(as_path(record).parent, "record", record)
        self.run_id = f"api-{uuid.uuid4().hex[:8]}"
        self.method, self.seed, self.localizer, self.selection = method, seed, localizer, selection
        self.record = as_path(record) if record is not None else None
        self.agents_per_process = agents_per_process
        self.start_timeout_s = start_timeout_s or max(30.0, 0.1 * self.trajectory.n)
        self.step_timeout_s = step_timeout_s
        self.hub: str | None = None
        self._procs: list[subprocess.Popen[bytes]] = []
        self._stack: contextlib.ExitStack | None = None
        self._hub_session: Any = None  # zenoh.Session of the hub (a router in this process)
        self._member: Any = None  # the coordinator's ZenohSettings
        self._state = "new"
        self._result: RunResult | None = None
        self._error: BaseException | None = None
        self._command = "inchworm.DistributedRun"  # the recording's metadata names what ran it

    def start(self) -> DistributedRun:
        """Open the hub and start the agent processes (once)."""
        from inchworm.processes import agents_per_process as per_process_for, start_agents  # noqa: PLC0415
        from inchworm.specs import AgentHostSpec  # noqa: PLC0415
        from runtime.wire.transport import open_loopback_hub  # noqa: PLC0415

        if self._state != "new":
            raise SwarmInputError(f"run {self.run_id} was already started")
        self._state = "running"
        with contextlib.ExitStack() as stack:
            stack.callback(self._stop_agents)
            hub_session, self._member, self.hub = open_loopback_hub()
            self._hub_session = stack.enter_context(hub_session)
            folder = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="inchworm-run-")))
            traj_file = folder / "trajectory.json"
            self.trajectory.save(traj_file)
            start_agents(self.trajectory, AgentHostSpec(run_id=self.run_id, robots=(), hub=self.hub, seed=self.seed, model=self.model),
                         self._procs, per_process_for(self.trajectory.n, self.agents_per_process), traj_file, stdout=subprocess.DEVNULL)
            self._stack = stack.pop_all()
        return self

    def running(self) -> bool:
        return self._state == "running"

    def status(self) -> SwarmStatus:
        """The run's live state (``inchworm.SwarmStatus``): its hub, and the agents and coordinators alive on it."""
        from coordinator.node.zenoh_backend import live_run  # noqa: PLC0415
        from inchworm.entry import exit_code  # noqa: PLC0415
        from inchworm.swarm import SwarmStatus  # noqa: PLC0415

        if self._state == "new":
            return SwarmStatus(self.run_id, "starting")
        if self._state == "ended":
            return SwarmStatus(self.run_id, "ended", self.hub, status=0 if self._error is None else exit_code(self._error))
        live = live_run(self._hub_session, self.run_id, timeout_s=0.5)
        return SwarmStatus(self.run_id, "running", self.hub, tuple(sorted(live.robots)), live.coordinators)

    def estop(self, reason: str = "inchworm.DistributedRun.estop", ack_timeout_s: float = 1.0) -> EstopOutcome:
        """The run-wide emergency stop, as ``swarm estop --run RUN`` sends it; who acknowledged it."""
        from coordinator.node.stop import emergency_stop  # noqa: PLC0415

        if self._state != "running":
            raise SwarmInputError(f"run {self.run_id} is not running")
        return emergency_stop(self._member, self.run_id, f"inchworm.DistributedRun (pid {os.getpid()})", reason, 0.0, ack_timeout_s)

    def wait(self) -> RunResult:
        """Run the coordinator in this thread (the main thread: Ctrl-C stops the run as it stops ``swarm coordinator``)
        until the run ends, stop the agents and return the ``RunResult``; raises a ``SwarmRunError`` (``AgentLost``,
        ``RunAborted``, ``RunStopped``, ...) when the agents do not come up or the run is aborted or stopped."""
        from coordinator.node.process import CoordinatorOptions, run_coordinator  # noqa: PLC0415
        from coordinator.node.stop import StopSignals  # noqa: PLC0415

        if self._state == "new":
            self.start()
        if self._state == "ended":
            return self.result()
        signals = StopSignals()
        try:
            options = CoordinatorOptions(self.trajectory, self.run_id, self._member, str(self.hub), self.method, self.seed, self.localizer,
                                         self.model, None, self.selection, self.start_timeout_s, self.step_timeout_s, record=self.record,
                                         command=self._command)
            outcome = run_coordinator(options, signals, log=lambda _line: None)
        except BaseException as exc:  # a stop signal, ...: the status says so
            self._error = exc
            raise
        finally:
            signals.restore()
            self.stop()
        if outcome.error is not None:
            self._error = outcome.error
            raise outcome.error
        assert outcome.result is not None  # no error: a result
        self._result = outcome.result
        return self._result

    def result(self) -> RunResult:
        """The ``RunResult`` of a run that ended (``SwarmInputError`` before)."""
        if self._result is None:
            raise SwarmInputError(f"run {self.run_id} has no result: " + ("wait() for it" if self._state != "ended" else "it failed or was stopped"))
        return self._result

    def stop(self) -> None:
        """Stop every agent process and close the hub (a run still waiting for its agents then fails)."""
        if self._stack is not None:
            self._stack.close()
            self._stack = None
        if self._state != "new":
            self._state = "ended"

    def _stop_agents(self) -> None:
        from inchworm.processes import stop_all  # noqa: PLC0415

        stop_all(self._procs)

    def __enter__(self) -> DistributedRun:
        return self.start()

    def __exit__(self, kind: type[BaseException] | None, value: BaseException | None, tb: TracebackType | None) -> None:
        self.stop()


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
    with DistributedRun(trajectory, method=method, robots=robots, configs=configs, seed=seed, model=model, localizer=localizer,
                        selection=selection, record=record, agents_per_process=agents_per_process, start_timeout_s=start_timeout_s,
                        step_timeout_s=step_timeout_s) as run:
        run._command = "inchworm.run_distributed"
        return run.wait()


__all__ = ["DistributedRun", "run_distributed"]
