"""The coordinator process of a distributed run (``swarm coordinator``).

Connects as a Zenoh client to the hub, waits for every robot's agent, then runs the
same ``InchwormExecutor`` as ``swarm sim`` over ``coordinator.node.zenoh_backend`` (which also
publishes every plan and estimate on ``swarm/<run>/coord/...``) and prints the
per-configuration summary (``swarm_cli.coordinator_cmd``).

Lost robots (docs/failure-model.md): with ``--on-lost continue`` (the default) a robot
that is lost (liveliness token gone, silent through a step, or refusing its command) is
stopped and the run goes on without it; the summary names it and P_f is over the robots
that finished. ``--on-lost abort``, or fewer than ``--min-robots`` robots left, ends the
run. Every abnormal end (an abort, an error, SIGTERM or Ctrl-C) first publishes a
run-wide ``EmergencyStop``, so no robot is left moving. Exit status: 0 done (also with
lost robots), 3 the run was aborted or the agents did not come up (the message names the
robots), 2 bad input.

One master per run (docs/protocol.md, Coordinator epochs): a coordinator started while another
coordinator of the run is alive ends at once with ``CoordinatorConflict`` naming the live one
(``swarm coordinator`` exits 4) and touches nothing (no recording, no stop). The run survives its
coordinator (docs/failure-model.md): the coordinator publishes a ``Checkpoint`` after the start,
every plan and every step, and goes on only once its recorder has it on the disk;
``standby`` follows a live coordinator's checkpoints and, when its token disappears without the
run having finished or been stopped, takes the run over from the last one; ``resume`` takes it
over from the last checkpoint recorded in an MCAP file. Either continues as the same run (same
step numbers, estimate, plan, lost robots, selection random state), so in simulation the result
is the fault-free run's. A coordinator that stalled beyond its session lease steps down when another one took
its run over meanwhile (``SteppedDown``, exit 4: it declares no robot lost and stops nothing); with nobody else
holding the run it goes on with every robot whose token is alive again (``coordinator.node.zenoh_backend``, Stalls).

Recording is on by default: before the run starts, a recorder (``runtime.recording.mcap_log.record_run``,
its own Zenoh client session on a background thread) subscribes to ``swarm/<run>/**`` and
writes every message to ``recordings/<run>.mcap`` (``--record PATH`` to choose, ``--no-record``
to turn it off), with the run metadata ``swarm replay --check`` and ``swarm plot`` need (seed,
method, localizer, model and selection configuration, trajectory). The coordinator waits until
the recorder's subscription has reached the hub before it starts, and at the end (also after a
failed or interrupted run) lets the last messages arrive, finishes the file and prints
``recorded PATH: N messages on C channels``.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import math
import os
import queue
import sys
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

from coordinator.node.stop import StopRequested, StopSignals, send_estop
from runtime.errors import OptionError, RecordingError, SwarmConnectionError
from runtime.models.config import ModelConfig
from runtime.models.trajectory import Trajectory
from runtime.wire.keys import run_wildcard, validate_run

if TYPE_CHECKING:  # imported where used: a parser importing this module must not load scipy, zenoh or matplotlib
    import numpy as np
    import zenoh

    from coordinator.checkpoint import RunState
    from coordinator.executor import ExecutorListener
    from coordinator.legs import LegRecord
    from coordinator.node.zenoh_backend import ZenohSwarmBackend
    from coordinator.plan import Plan
    from coordinator.run_result import ContactEvent, RunResult
    from coordinator.selection.selector import Selection, SelectionConfig
    from runtime.models.state import SwarmEstimate
    from runtime.recording.foxglove_live import LiveView
    from runtime.recording.mcap_log import McapRecorder
    from runtime.wire.transport import ZenohSettings

EXIT_OUTPUT = 5  # an output (recording, result, plots) could not be written: the status the launcher reads (inchworm.entry.EXIT_CODES)
INITIAL_DELTA = 0.01  # m, as coordinator.simulate.simulate
INITIAL_HEADING_SIGMA = math.radians(2.0)


def default_recording(run_id: str, role: str = "") -> Path:
    """``recordings/<run>.mcap``; a standby or resuming coordinator (``role``) records to ``recordings/<run>.<role>.mcap``."""
    return Path("recordings") / (f"{run_id}.{role}.mcap" if role else f"{run_id}.mcap")


def result_json(result: RunResult) -> dict[str, Any]:
    """Every step's estimate (and truth, when known) as plain JSON."""
    def truth(t: np.ndarray | None) -> list[Any] | None:
        return None if t is None else t.tolist()

    return {
        "method": result.method,
        "ids": result.initial_estimate.ids.tolist(),
        "initial_estimate": result.initial_estimate.poses.tolist(),
        "initial_truth": truth(result.initial_truth),
        "lost": [{"robot": r.robot, "step": r.step, "config": r.config + 1, "reason": r.reason} for r in result.lost],
        "rejoined": [{"robot": r.robot, "step": r.step, "config": r.config + 1} for r in result.rejoined],
        "steps": [
            {"config": s.config, "step": s.step, "ids": s.estimate.ids.tolist(), "moving": s.moving.tolist(), "commands": s.commands.tolist(),
             "poses": s.estimate.poses.tolist(), "cov": s.estimate.cov.tolist(), "truth": truth(s.truth), "fallback": s.fallback}
            for s in result.steps
        ],
        "final": result.configs[-1].estimate.poses.tolist() if result.configs else None,
    }


@dataclass(frozen=True)
class CoordinatorOptions:
    """One distributed run as the coordinator runs it (SI units; timeouts in seconds)."""

    trajectory: Trajectory
    run_id: str
    settings: ZenohSettings
    hub: str  # what the connection options said, for the metadata
    method: str = "inchworm"
    seed: int = 0
    localizer: str = "paper"
    model: ModelConfig = field(default_factory=ModelConfig)
    model_file: Path | None = None  # the model file ``model`` was read from, if any (kept in the metadata)
    selection: SelectionConfig | None = None  # None: the default search
    start_timeout_s: float = 30.0
    step_timeout_s: float = 5.0
    on_lost: str = "continue"
    min_robots: int = 2
    truth: bool = True  # False: hardware without ground truth, no TruthMessages awaited
    record: Path | None = None  # the MCAP file, None: no recording
    on_record_error: str = "continue"  # when writing the recording fails: go on unrecorded, or "stop" the run
    foxglove_port: int | None = None  # serve the live view on this port
    command: str = ""  # the command line, for the metadata
    standby: bool = False  # follow the live coordinator; take the run over from its last checkpoint if it dies
    resume: Path | None = None  # take the run over from the last checkpoint in this recording
    rejoin: bool = True  # a lost robot whose agent comes back rejoins at the next configuration


def run_metadata(o: CoordinatorOptions, selection: SelectionConfig) -> dict[str, Any]:
    """What a recording needs to re-run the coordinator's decisions (``swarm replay --check``, ``swarm plot``)."""
    return {
        "source": "swarm coordinator",
        "command": o.command,
        "hub": o.hub,
        "seed": o.seed,
        "method": o.method,
        "localizer": o.localizer,
        "model": o.model.to_dict(),
        "model_file": None if o.model_file is None else Path(o.model_file).name,  # its values are in "model"; no machine path
        "selection": dataclasses.asdict(selection),
        "trajectory": o.trajectory.to_json(),
        "initial_delta_m": INITIAL_DELTA,
        "initial_heading_sigma_rad": INITIAL_HEADING_SIGMA,
        "step_timeout_s": o.step_timeout_s,
    }


class RecordingStopped(RecordingError):
    """``on_record_error="stop"``: the recording failed, so the run is stopped."""


class Recording:
    """``record_run`` on a background thread: started (subscription declared) on construction, ``finish()`` at the end.

    A write error during the run is reported at once (one line, ``policy`` said) and sets ``failed``."""

    SETTLE_S = 0.3  # the file is closed once no message arrived for this long ...
    SETTLE_MAX_S = 3.0  # ... or after this long

    def __init__(self, settings: ZenohSettings, run_id: str, path: Path, metadata: dict[str, Any], timeout_s: float = 15.0,
                 policy: str = "continue") -> None:
        self.run_id, self.path, self.policy = run_id, path, policy
        self.stop = threading.Event()
        self.failed = threading.Event()
        self._ready = threading.Event()
        self.recorder: McapRecorder | None = None
        self.result: dict[str, Any] = {}
        self.error: BaseException | None = None
        from runtime.recording.mcap_log import RecordingFailed, record_run  # noqa: PLC0415

        def target() -> None:
            try:
                self.result.update(record_run(settings, run_id, path, metadata, self.stop, on_ready=self._on_ready,
                                              on_error=self._on_error))
            except RecordingFailed as exc:  # the run is not an error for it
                if not self.failed.is_set():  # failed only while finishing the file: the one line now
                    self._on_error(exc.error)
                self.error = exc
                self.failed.set()
            except BaseException as exc:  # noqa: BLE001 - reported by the main thread
                self.error = exc
            finally:
                self._ready.set()

        self.thread = threading.Thread(target=target, name="swarm-recorder", daemon=True)
        self.thread.start()
        if not self._ready.wait(timeout_s):
            self.stop.set()
            raise SwarmConnectionError(f"the recorder did not start within {timeout_s:.0f} s")
        if self.error is not None:
            raise self.error

    def _on_ready(self, recorder: McapRecorder) -> None:
        self.recorder = recorder
        self._ready.set()

    def _on_error(self, error: BaseException) -> None:  # the recorder's writer thread
        detail = error.strerror if isinstance(error, OSError) and error.strerror else str(error) or type(error).__name__
        then = "the run goes on unrecorded" if self.policy == "continue" else "stopping the run"
        print(f"coordinator: error: recording to {self.path} failed after {self.recorder.count if self.recorder else 0} "
              f"messages: {detail}; {then} (--on-record-error {self.policy})", file=sys.stderr, flush=True)
        self.failed.set()

    def check(self) -> None:
        """``RecordingStopped`` if the recording failed and the policy is to stop the run."""
        failed = self.failed.is_set() or (self.recorder is not None and self.recorder.error is not None)
        if self.policy == "stop" and failed:
            raise RecordingStopped(f"the recording to {self.path} failed (the policy for a recording error is stop)")

    def wait_subscribed(self, session: zenoh.Session, timeout_s: float = 10.0) -> None:
        """Until the hub knows the recorder's subscription (so nothing published from now on is missed)."""
        probe = session.declare_publisher(f"swarm/{self.run_id}/recorder-probe/{uuid.uuid4().hex}")  # never published on
        try:
            deadline = time.monotonic() + timeout_s
            while not cast("zenoh.MatchingStatus", probe.matching_status).matching:  # zenoh's stub says bool
                if time.monotonic() > deadline or self.error is not None:
                    raise SwarmConnectionError(f"the recorder's subscription did not reach the hub within {timeout_s:.0f} s")
                time.sleep(0.005)
        finally:
            probe.undeclare()

    def finish(self, interrupted: bool = False) -> dict[str, Any] | None:
        """Let the last messages arrive, stop, finish the file; ``{"path", "messages", "channels", "undecodable"}``,
        or None when writing failed (``error`` says why; the file holds what reached the disk).

        ``interrupted``: the run was stopped by a signal; wait at most ``SETTLE_S`` for late messages
        (the launcher's grace period is short). Call it with signals deferred (``StopSignals.deferred``).
        """
        if self.recorder is not None and self.thread.is_alive():
            start = last_change = time.monotonic()
            count = self.recorder.count
            settle_max = self.SETTLE_S if interrupted else self.SETTLE_MAX_S
            while time.monotonic() - last_change < self.SETTLE_S and time.monotonic() - start < settle_max:
                time.sleep(0.05)
                if self.recorder.count != count:
                    count, last_change = self.recorder.count, time.monotonic()
        self.stop.set()
        self.thread.join(timeout=30)
        if self.failed.is_set():
            return None
        if self.error is not None:
            raise RecordingError(f"recording to {self.path} failed: {self.error}") from self.error
        return self.result


class _Checked:
    """The executor's listener (the backend), followed by ``check()`` after every plan, estimate and contact report."""

    def __init__(self, listener: ExecutorListener, check: Callable[[], None]) -> None:
        self.listener, self.check = listener, check

    def on_plan(self, config_index: int, first_step: int, plan: Plan, selection: Selection | None) -> None:
        self.listener.on_plan(config_index, first_step, plan, selection)
        self.check()

    def on_leg(self, config_index: int, leg: int, first_step: int, record: LegRecord) -> None:
        on_leg = getattr(self.listener, "on_leg", None)
        if on_leg is not None:
            on_leg(config_index, leg, first_step, record)
        self.check()

    def on_estimate(self, step: int, estimate: SwarmEstimate) -> None:
        self.listener.on_estimate(step, estimate)
        self.check()

    def on_contacts(self, contacts: list[ContactEvent]) -> None:
        self.listener.on_contacts(contacts)
        self.check()


def recording_line(rec: dict[str, Any]) -> str:
    from runtime.recording.mcap_log import counts_text  # noqa: PLC0415

    return (f"recorded {rec['path']}: {counts_text(rec)}"
            + (f" ({rec['undecodable']} undecodable)" if rec.get("undecodable") else ""))


class Live:
    """The ``--foxglove`` view of a run; ``keep`` (set once the run is done) keeps it open for ``linger``."""

    def __init__(self, view: LiveView | None) -> None:
        self.view, self.keep = view, False

    def linger(self, seconds: float | None) -> None:
        if self.view is None:
            return
        if seconds != 0:
            until = "until Ctrl-C" if seconds is None else f"for {seconds:g} s"
            say(f"the run is over; the live view keeps serving at {self.view.url} {until}")
            self.view.linger(seconds)
        self.view.close()




def say(text: str) -> None:
    """A progress line of the coordinator process on stderr."""
    print(f"coordinator: {text}", file=sys.stderr, flush=True)


@contextlib.contextmanager
def live_view(o: CoordinatorOptions, session: Any, log: Callable[[str], None] = say) -> Iterator[Live]:
    """With ``foxglove_port``: every message of the run also goes to a Foxglove live view while it runs;
    the view is closed at the end unless ``keep`` was set (then ``Live.linger`` closes it)."""
    if o.foxglove_port is None:
        yield Live(None)
        return
    from runtime.recording.foxglove_live import LiveView  # noqa: PLC0415 - foxglove-sdk only with a live view
    from runtime.wire.transport import subscribe  # noqa: PLC0415

    view = LiveView(o.foxglove_port, trajectory=o.trajectory.to_json(), robot_radius=o.model.robot_radius_m)
    live = Live(view)
    subscriber = subscribe(session, run_wildcard(o.run_id), view.handle)
    log(f"live view for the Foxglove app at {view.url}")
    try:
        yield live
    finally:
        subscriber.undeclare()
        if not live.keep:
            view.close()


@dataclass
class CoordinatorOutcome:
    """What a coordinator run ended with: the run (None if it failed), the recording's counts, the live view, the error."""

    result: RunResult | None  # with ``error`` set: the configurations completed before the end (None if nothing ran)
    recording: dict[str, Any] | None
    live: Live
    error: Exception | None = None  # the agents did not come up, the run was aborted (lost robots) or stopped (recording)
    recording_error: BaseException | None = None  # why the recording could not be written (it keeps what reached the disk)


def run_coordinator(o: CoordinatorOptions, signals: StopSignals, on_config: Callable[[int, int, int], None] | None = None,
                    log: Callable[[str], None] = say) -> CoordinatorOutcome:
    """Record, wait for every agent, run the executor over Zenoh; e-stop every robot on any abnormal end.

    ``signals`` (the caller's, made first) turn SIGINT/SIGTERM into a stop that never interrupts
    finishing the recording. ``on_config(done, total, step)`` is told each configuration as it ends,
    ``log`` the progress lines of the process (default: stderr).
    A failed or interrupted run still finishes its recording (printed as ``recorded PATH ...``).
    """
    from coordinator.executor import InchwormExecutor, RunAborted  # noqa: PLC0415 - the run's imports, not a parser's
    from coordinator.localization import make_localizer  # noqa: PLC0415
    from coordinator.node.zenoh_backend import (  # noqa: PLC0415
        AgentError,
        CoordinatorConflict,
        HubLost,
        Timeouts,
        ZenohSwarmBackend,
        conflict_message,
        live_coordinators,
    )
    from coordinator.selection.selector import SelectionConfig  # noqa: PLC0415
    from coordinator.simulate import initial_estimate  # noqa: PLC0415
    from coordinator.strategies import make_strategy  # noqa: PLC0415
    from runtime.models.trajectory import validate_connected, validate_passable  # noqa: PLC0415
    from runtime.wire.transport import open_session  # noqa: PLC0415

    traj, cfg = o.trajectory, o.model
    selection = o.selection or SelectionConfig()
    validate_connected(traj, cfg.sensing_range_m)
    validate_passable(traj, cfg)
    if not 2 <= o.min_robots <= traj.n:
        raise OptionError("min_robots", f"{o.min_robots}: must be between 2 and the {traj.n} robots of the trajectory")
    localizer = make_localizer(o.localizer, cfg)  # the executor's and the selection's
    strategy = make_strategy(o.method, traj.n, cfg, localizer, selection, o.seed)  # bad input fails before waiting
    validate_run(o.run_id)
    initial = initial_estimate(traj, o.seed, INITIAL_DELTA, INITIAL_HEADING_SIGMA)
    taken: tuple[int, RunState | None] | None = read_checkpoint(o.resume, o.run_id, traj, initial) if o.resume is not None else None
    recording = None
    recorded, completed, result = None, False, None
    error: Exception | None = None
    live = Live(None)
    try:
        if signals.received is not None:
            raise StopRequested(signals.received)
        with open_session(o.settings) as session, live_view(o, session, log) as live:
            live_now = live_coordinators(session, o.run_id)
            if live_now and not o.standby:  # before anything is recorded or stopped: this run has a master
                completed = True  # not ours to stop
                return CoordinatorOutcome(None, None, live, CoordinatorConflict(conflict_message(o.run_id, live_now)))
            standby = Standby(session, o.run_id, traj, initial) if o.standby else None
            if o.record is not None:
                with signals.deferred():  # a signal now would leave the recorder thread with an unfinished file
                    recording = Recording(o.settings, o.run_id, o.record, run_metadata(o, selection), policy=o.on_record_error)
                log(f"recording swarm/{o.run_id}/** to {o.record}")
                recording.wait_subscribed(session)
            if standby is not None:
                waited = standby.wait(o.start_timeout_s, signals)
                if isinstance(waited, str):  # the run finished or was stopped: nothing to take over
                    log(f"standby: {waited}; nothing to take over")
                    completed = True
                    stopped = None if waited.startswith("the run finished") else AgentError(waited, [])
                    return CoordinatorOutcome(None, None, live, stopped)
                taken = waited
            parent, state = taken if taken is not None else (0, None)
            try:
                backend = ZenohSwarmBackend(session, o.run_id, traj.ids.tolist(), Timeouts(o.start_timeout_s, o.step_timeout_s),
                                            simulated=o.truth, parent=parent, rejoin=o.rejoin,
                                            robot_radius_m=cfg.robot_radius_m)
            except CoordinatorConflict as exc:
                completed = True  # not ours to stop
                return CoordinatorOutcome(None, None, live, exc)
            backend.stop_requested = lambda: signals.received is not None  # agents leaving with our stop signal are not lost
            ended: BaseException | None = None
            partial = None
            try:
                if state is not None:
                    backend.resume(state)
                    log(f"epoch {backend.epoch} takes over run {o.run_id} from epoch {parent} after step {state.step}")
                    if state.dropped:
                        log(f"the checkpoint could not carry the estimate's {', '.join(state.dropped)} (too large for a "
                            "message): the run goes on from per-robot covariances, not bit for bit as without the takeover")
                backend.wait_for_agents()
                log(f"{len(backend.ids)} agents alive, run {o.run_id}, epoch {backend.epoch}")
                progress = lambda done, total: on_config(done, total, backend.step) if on_config else None  # noqa: E731
                listener = backend if recording is None else _Checked(backend, recording.check)
                executor = InchwormExecutor(backend, localizer, strategy, cfg, progress, listener=listener,
                                            on_lost=o.on_lost, min_robots=o.min_robots,
                                            on_checkpoint=durable_checkpoints(backend, recording))
                try:
                    result = executor.run(traj, initial, resume=state)
                finally:
                    partial = executor.result  # the configurations completed, however the run ends
                completed = live.keep = True
            except CoordinatorConflict as exc:  # it stepped down: another coordinator holds the run, not ours to stop
                completed = True
                ended = error = exc
            except (AgentError, RunAborted, RecordingStopped) as exc:
                ended = error = exc
                result = getattr(exc, "result", None) or (partial if isinstance(exc, (RecordingStopped, HubLost)) else None)
            except BaseException as exc:
                ended = exc
                raise
            finally:
                with signals.deferred():
                    if not completed:  # whatever ended the run early: no robot may be left moving
                        send_estop(session, o.run_id, f"swarm coordinator (pid {os.getpid()})",
                                   f"the run ended early ({type(ended).__name__}: {ended})"[:2000])
                    backend.close()
    finally:
        if recording is not None:
            with signals.deferred():
                recorded = recording.finish(interrupted=signals.received is not None)
            if result is None:  # failed, interrupted or nothing to do: the caller prints no summary
                print(recording_line(recorded) if recorded else f"recording failed: {recording.error}", flush=True)
    return CoordinatorOutcome(result, recorded, live, error, None if recording is None else recording.error)


def durable_checkpoints(backend: ZenohSwarmBackend, recording: Recording | None,
                        timeout_s: float = 2.0) -> Callable[[RunState], None]:
    """The executor's ``on_checkpoint``: publish the state and, when recording, go on only once the recorder has
    it on the disk (so ``--resume`` from this recording finds every checkpoint the agents may have acted on); with
    ``--on-record-error stop`` a recording that failed meanwhile stops the run here, before the next step (the
    recorder writes in order: whatever the step published is on the disk, or failed, once its checkpoint is)."""
    def checkpoint(state: RunState) -> None:
        recorder = None if recording is None or recording.failed.is_set() else recording.recorder  # a failed one stores none
        written = 0 if recorder is None else recorder.checkpoints
        backend.publish_checkpoint(state)
        if recorder is not None and not recorder.wait_checkpoints(written + 1, timeout_s):
            logging.getLogger(__name__).warning("the recorder did not store the checkpoint of step %d within %.0f s",
                                                state.step, timeout_s)
        if recording is not None:
            recording.check()
    return checkpoint


def read_checkpoint(path: Path, run_id: str, traj: Trajectory, initial: SwarmEstimate) -> tuple[int, RunState]:
    """``(epoch, state)`` of the last ``Checkpoint`` of run ``run_id`` recorded in ``path`` (``--resume``)."""
    from coordinator.checkpoint import RunState  # noqa: PLC0415
    from runtime.recording.mcap_log import read_messages  # noqa: PLC0415
    from runtime.wire.keys import coord_key  # noqa: PLC0415
    from runtime.wire.messages import Checkpoint, MessageError, decode  # noqa: PLC0415

    if not path.is_file():
        raise OptionError("resume", f"{path}: no such file")
    key, last = coord_key(run_id, "checkpoint"), None
    for topic, payload, _, _ in read_messages(path):
        if topic == key:
            try:
                last = decode(payload, Checkpoint, key=key)
            except MessageError:
                continue
    if last is None:
        raise OptionError("resume", f"{path}: no checkpoint of run {run_id} in this recording")
    state = RunState.from_json(last.state, traj, initial)
    if state.finished:
        raise OptionError("resume", f"{path}: run {run_id} finished (epoch {last.epoch}); nothing to resume")
    return last.epoch, state


class Standby:
    """``--standby``: follows the checkpoints of the run's live coordinator until its token disappears."""

    def __init__(self, session: zenoh.Session, run_id: str, traj: Trajectory, initial: SwarmEstimate) -> None:
        from runtime.wire.keys import coord_alive_key, coord_key, estop_key, parse_coord_token  # noqa: PLC0415
        from runtime.wire.messages import Checkpoint, DropCounter, EmergencyStop, decode_or_drop  # noqa: PLC0415
        from runtime.wire.transport import subscribe, watch_liveliness  # noqa: PLC0415

        self.run_id, self.traj, self.initial = run_id, traj, initial
        self.latest: dict[int, Checkpoint] = {}  # by epoch
        self.stopped: str | None = None
        self.events: queue.SimpleQueue[tuple[tuple[int, int], bool]] = queue.SimpleQueue()
        drops = DropCounter(logging.getLogger(__name__))

        def on_checkpoint(key: str, payload: bytes) -> None:
            msg = decode_or_drop(payload, drops, key, Checkpoint)
            if msg is not None and (msg.epoch not in self.latest or msg.step >= self.latest[msg.epoch].step):
                self.latest[msg.epoch] = msg  # a replayed older checkpoint never replaces a newer one

        def on_estop(key: str, payload: bytes) -> None:
            msg = decode_or_drop(payload, drops, key, EmergencyStop)
            if msg is not None and not msg.robots:
                self.stopped = f"the run was stopped by {msg.source} ({msg.reason})"

        def on_token(key: str, alive: bool) -> None:
            token = parse_coord_token(key)
            if token is not None:
                self.events.put((token, alive))

        self._subs = [watch_liveliness(session, coord_alive_key(run_id), on_token), subscribe(session, estop_key(run_id), on_estop),
                      subscribe(session, coord_key(run_id, "checkpoint"), on_checkpoint)]  # last: its match says "ready"

    def wait(self, timeout_s: float, signals: StopSignals) -> tuple[int, RunState | None] | str:
        """``(epoch, state)`` to take over once the followed coordinator is gone (``state`` None: it died before
        its first checkpoint), or why there is nothing to take over."""
        from coordinator.checkpoint import RunState  # noqa: PLC0415

        live: dict[int, int] = {}
        followed: int | None = None
        deadline = time.monotonic() + timeout_s
        try:
            while True:
                if signals.received is not None:
                    raise StopRequested(signals.received)
                try:
                    (epoch, parent), alive = self.events.get(timeout=0.05)
                except queue.Empty:
                    if followed is None and time.monotonic() > deadline:
                        return f"no coordinator of run {self.run_id} appeared within {timeout_s:.0f} s"
                    continue
                if alive:
                    live[epoch] = parent
                    if followed is None:
                        followed = epoch
                        say(f"standby for run {self.run_id}, following epoch {epoch}")
                    continue
                live.pop(epoch, None)
                if epoch != followed:
                    continue
                if live:  # another coordinator took over first: follow it
                    followed = min(live)
                    continue
                checkpoint = self.latest.get(epoch)
                if self.stopped is not None:
                    return self.stopped
                if checkpoint is None:
                    return epoch, None
                state = RunState.from_json(checkpoint.state, self.traj, self.initial)
                if state.finished:
                    return f"the run finished (epoch {epoch})"
                return epoch, state
        finally:
            for sub in self._subs:
                sub.undeclare()
