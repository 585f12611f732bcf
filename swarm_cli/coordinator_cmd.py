"""``swarm coordinator``: the coordinator process of a distributed run.

    swarm coordinator --trajectory traj.json --run demo --hub tcp/127.0.0.1:7447 --seed 0 --method inchworm

Connects as a Zenoh client to the hub, waits for every robot's agent, then runs the
same ``InchwormExecutor`` as ``swarm sim`` over ``coordinator.zenoh_backend`` (which also
publishes every plan and estimate on ``swarm/<run>/coord/...``) and prints the
per-configuration summary; with ``--out DIR`` it also writes ``trajectory.png`` (Fig.
13/14) and ``errors.png`` (Fig. 17, needs the simulated truth) there, as ``swarm sim`` does.

Lost robots (docs/failure-model.md): with ``--on-lost continue`` (the default) a robot
that is lost (liveliness token gone, silent through a step, or refusing its command) is
stopped and the run goes on without it; the summary names it and P_f is over the robots
that finished. ``--on-lost abort``, or fewer than ``--min-robots`` robots left, ends the
run. Every abnormal end (an abort, an error, SIGTERM or Ctrl-C) first publishes a
run-wide ``EmergencyStop``, so no robot is left moving. A run ended by lost robots (``--on-lost
abort``, fewer than ``--min-robots`` left, or the robots left unable to reach the next
configuration) names them and still prints the summary of the configurations it completed
and writes ``--result`` and the plots. Exit status: 0 done (also with lost robots), 3 the run
was ended by lost robots or the agents did not come up (the message names the robots), 4
the recording, ``--result`` or a plot could not be written (each failure is one line; the
other outputs are still written) or the run was stopped because its recording failed
(``--on-record-error stop``), 2 bad input, 128 + N after signal N (SIGINT, SIGTERM, SIGHUP).

Recording is on by default: before the run starts, a recorder (``runtime.recording.mcap_log.record_run``,
its own Zenoh client session on a background thread) subscribes to ``swarm/<run>/**`` and
writes every message to ``recordings/<run>.mcap`` (``--record PATH`` to choose, ``--no-record``
to turn it off), with the run metadata ``swarm replay --check`` and ``swarm plot`` need (seed,
method, localizer, model and selection configuration, trajectory). The coordinator waits until
the recorder's subscription has reached the hub before it starts, and at the end (also after a
failed or interrupted run) lets the last messages arrive, finishes the file and prints
``recorded PATH: N messages on C channels``. A recording that fails (disk full, file size
limit, device gone) is one line on stderr at once, ``coordinator: error: recording to PATH
failed after N messages: No space left on device; ...``; with ``--on-record-error continue``
(the default) the run goes on unrecorded, with ``stop`` it is stopped as an error (run-wide
``EmergencyStop``, exit 4). Either way the file keeps what reached the disk and the summary,
``--json``, ``--result`` and plots are written.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import logging
import math
import os
import sys
import threading
import time
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

from coordinator.strategies import METHODS
from runtime.errors import SwarmInputError
from runtime.wire.keys import run_wildcard, validate_run
from runtime.models.trajectory import Trajectory
from swarm_cli.entry import StopRequested, StopSignals, leave, run_standalone
from swarm_cli.options import add_connection_options, add_simulation_options, connection_label, connection_settings, model_config, print_json, selection_config

if TYPE_CHECKING:  # imported where used: building the parser (--help) must not load scipy, zenoh or matplotlib
    from coordinator.executor import RunResult
    from runtime.recording.foxglove_live import LiveView
    from runtime.recording.mcap_log import McapRecorder
    from runtime.wire.transport import ZenohSettings

EXIT_AGENT = 3
EXIT_OUTPUT = 4  # an output (recording, result, plots) could not be written; the run itself ended normally or was stopped for it
INITIAL_DELTA = 0.01  # m, as coordinator.simulate.simulate
INITIAL_HEADING_SIGMA = math.radians(2.0)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("coordinator", help="run the coordinator of a distributed run (agents started separately)")
    add_arguments(p)
    p.set_defaults(run=run)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--trajectory", type=Path, required=True, help="trajectory JSON (docs/trajectory.md)")
    p.add_argument("--run", dest="run_id", required=True, help="run id (the key space swarm/<run>/...)")
    add_connection_options(p)
    p.add_argument("--method", choices=METHODS, default="inchworm", help="motion strategy (default inchworm)")
    p.add_argument("--seed", type=int, default=0, help="seed of the run: initial estimate and search (default 0)")
    p.add_argument("--start-timeout", type=float, default=30.0, help="seconds to wait for all agents (default 30)")
    p.add_argument("--step-timeout", type=float, default=5.0, help="seconds to wait for the answers of a step (default 5)")
    p.add_argument("--on-lost", choices=("continue", "abort"), default="continue",
                   help="when a robot is lost: stop it and go on without it, or end the run (default continue)")
    p.add_argument("--min-robots", type=int, default=2,
                   help="end the run when fewer robots than this are left (default 2, the least localization needs)")
    p.add_argument("--no-truth", action="store_true",
                   help="no ground truth comes with this run (hardware without motion capture): do not wait for TruthMessages")
    p.add_argument("--result", type=Path, help="write the estimates of every step (and the truth) to this JSON file")
    p.add_argument("--out", type=Path, help="folder for the PNG plots trajectory.png and errors.png (default: no plots)")
    add_record_options(p)
    add_simulation_options(p)


def add_record_options(p: argparse.ArgumentParser) -> None:
    g = p.add_mutually_exclusive_group()
    g.add_argument("--record", type=Path, default=None, metavar="PATH",
                   help="MCAP file recording every message of the run (default recordings/<run>.mcap)")
    g.add_argument("--no-record", action="store_true", help="do not record the run")
    p.add_argument("--on-record-error", choices=("continue", "stop"), default="continue",
                   help="when writing the recording fails (disk full ...): go on unrecorded, or stop the run (default continue)")
    p.add_argument("--foxglove", type=int, nargs="?", const=8765, default=None, metavar="PORT",
                   help="serve the live swarm view on a Foxglove WebSocket (default port 8765; needs pip install -e '.[foxglove]')")
    p.add_argument("--linger", type=float, default=None, metavar="SECONDS",
                   help="with --foxglove: keep serving the live view this long after the run (default: until Ctrl-C; 0: exit at once)")


def default_recording(run_id: str) -> Path:
    return Path("recordings") / f"{run_id}.mcap"


def result_json(result: RunResult) -> dict:
    """Every step's estimate (and truth, when known) as plain JSON."""
    def truth(t):
        return None if t is None else t.tolist()

    return {
        "method": result.method,
        "ids": result.initial_estimate.ids.tolist(),
        "initial_estimate": result.initial_estimate.poses.tolist(),
        "initial_truth": truth(result.initial_truth),
        "lost": [{"robot": r.robot, "step": r.step, "config": r.config + 1, "reason": r.reason} for r in result.lost],
        "steps": [
            {"config": s.config, "step": s.step, "ids": s.estimate.ids.tolist(), "moving": s.moving.tolist(), "commands": s.commands.tolist(),
             "poses": s.estimate.poses.tolist(), "cov": s.estimate.cov.tolist(), "truth": truth(s.truth), "fallback": s.fallback}
            for s in result.steps
        ],
        "final": result.configs[-1].estimate.poses.tolist() if result.configs else None,
    }


def run_metadata(args: argparse.Namespace, traj: Trajectory, cfg, selection) -> dict:
    """What a recording needs to re-run the coordinator's decisions (``swarm replay --check``, ``swarm plot``)."""
    return {
        "source": "swarm coordinator",
        "command": " ".join(sys.argv),
        "hub": connection_label(args),
        "seed": args.seed,
        "method": args.method,
        "localizer": args.localizer,
        "model": cfg.to_dict(),
        "model_file": None if getattr(args, "model", None) is None else str(Path(args.model).resolve()),
        "selection": dataclasses.asdict(selection),
        "trajectory": traj.to_json(),
        "initial_delta_m": INITIAL_DELTA,
        "initial_heading_sigma_rad": INITIAL_HEADING_SIGMA,
        "step_timeout_s": args.step_timeout,
    }


class RecordingStopped(Exception):
    """``--on-record-error stop``: the recording failed, so the run is stopped."""


class Recording:
    """``record_run`` on a background thread: started (subscription declared) on construction, ``finish()`` at the end.

    A write error during the run is reported at once (one line, ``policy`` said) and sets ``failed``."""

    SETTLE_S = 0.3  # the file is closed once no message arrived for this long ...
    SETTLE_MAX_S = 3.0  # ... or after this long

    def __init__(self, settings: ZenohSettings, run_id: str, path: Path, metadata: dict, timeout_s: float = 15.0,
                 policy: str = "continue") -> None:
        self.run_id, self.path, self.policy = run_id, path, policy
        self.stop = threading.Event()
        self.failed = threading.Event()
        self._ready = threading.Event()
        self.recorder: McapRecorder | None = None
        self.result: dict = {}
        self.error: BaseException | None = None
        from runtime.recording.mcap_log import RecordingFailed, record_run  # noqa: PLC0415

        def target() -> None:
            try:
                self.result.update(record_run(settings, run_id, path, metadata, self.stop, on_ready=self._on_ready,
                                              on_error=self._on_error))
            except RecordingFailed as exc:  # reported by finish(); the run is not an error for it
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
            raise ConnectionError(f"the recorder did not start within {timeout_s:.0f} s")
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
        if self.policy == "stop" and self.failed.is_set():
            raise RecordingStopped(f"the recording to {self.path} failed (--on-record-error stop)")

    def wait_subscribed(self, session, timeout_s: float = 10.0) -> None:
        """Until the hub knows the recorder's subscription (so nothing published from now on is missed)."""
        probe = session.declare_publisher(f"swarm/{self.run_id}/recorder-probe/{uuid.uuid4().hex}")  # never published on
        try:
            deadline = time.monotonic() + timeout_s
            while not probe.matching_status.matching:
                if time.monotonic() > deadline or self.error is not None:
                    raise ConnectionError(f"the recorder's subscription did not reach the hub within {timeout_s:.0f} s")
                time.sleep(0.005)
        finally:
            probe.undeclare()

    def finish(self, interrupted: bool = False) -> dict | None:
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
            raise RuntimeError(f"recording to {self.path} failed: {self.error}") from self.error
        return self.result


class _Checked:
    """The executor's listener (the backend), followed by ``check()`` after every plan and estimate."""

    def __init__(self, listener, check) -> None:
        self.listener, self.check = listener, check

    def on_plan(self, *args) -> None:
        self.listener.on_plan(*args)
        self.check()

    def on_estimate(self, *args) -> None:
        self.listener.on_estimate(*args)
        self.check()


def recording_line(rec: dict) -> str:
    from runtime.recording.mcap_log import counts_text  # noqa: PLC0415

    return (f"recorded {rec['path']}: {counts_text(rec)}"
            + (f" ({rec['undecodable']} undecodable)" if rec.get("undecodable") else ""))


def print_summary(result: RunResult, args: argparse.Namespace, plots: list[str] | None = None, recording: dict | None = None,
                  failure: BaseException | None = None) -> None:
    """The per-configuration table of ``swarm sim``, then the run's outcome (``failure``: why the recording failed)."""
    from swarm_cli.summary import print_config_table  # noqa: PLC0415

    rows, fallbacks = print_config_table(result)
    for lost in result.lost:
        print(f"lost robot {lost.robot} after step {lost.step} (config {lost.config + 1}): {lost.reason}")
    pf = result.pf() if result.has_truth and result.configs else None
    over = f", over the {len(result.finished_ids)} robots that finished" if result.lost else ""
    print(f"P_f = {pf:.4f} ({args.method}, {args.localizer} localizer, distributed{over})" if pf is not None else "P_f: no ground truth")
    if plots:
        print(f"wrote {', '.join(plots)}")
    if recording:
        print(recording_line(recording))
    elif failure is not None:
        print(f"recording failed: {failure}")
    if args.json:
        print_json({"method": args.method, "localizer": args.localizer, "seed": args.seed, "pf": pf, "configs": rows,
                    "lost": [{"robot": r.robot, "step": r.step, "reason": r.reason} for r in result.lost],
                    "finished_robots": len(result.finished_ids),
                    "fallback_steps": len(fallbacks), "plots": plots or [], "recording": recording["path"] if recording else None})


class Live:
    """The ``--foxglove`` view of a run; ``keep`` (set once the run is done) keeps it open for ``linger``."""

    def __init__(self, view: LiveView | None) -> None:
        self.view, self.keep = view, False

    def linger(self, seconds: float | None) -> None:
        if self.view is None:
            return
        if seconds != 0:
            until = "until Ctrl-C" if seconds is None else f"for {seconds:g} s"
            print(f"coordinator: the run is over; the live view keeps serving at {self.view.url} {until}", file=sys.stderr, flush=True)
            self.view.linger(seconds)
        self.view.close()


@contextlib.contextmanager
def live_view(args: argparse.Namespace, traj: Trajectory, session) -> Iterator[Live]:
    """With ``--foxglove``: every message of the run also goes to a Foxglove live view while it runs;
    the view is closed at the end unless ``keep`` was set (then ``Live.linger`` closes it)."""
    if args.foxglove is None:
        yield Live(None)
        return
    from runtime.recording.foxglove_live import LiveView  # noqa: PLC0415 - foxglove-sdk only with --foxglove
    from runtime.wire.transport import subscribe  # noqa: PLC0415

    live = Live(LiveView(args.foxglove, trajectory=traj.to_json()))
    subscriber = subscribe(session, run_wildcard(args.run_id), live.view.handle)
    print(f"coordinator: live view for the Foxglove app at {live.view.url}", file=sys.stderr, flush=True)
    try:
        yield live
    finally:
        subscriber.undeclare()
        if not live.keep:
            live.view.close()


def run(args: argparse.Namespace) -> int:
    logging.basicConfig(level=logging.WARNING, format="coordinator: %(levelname)s %(message)s", stream=sys.stderr)
    signals = StopSignals()  # SIGINT/SIGTERM end the run; never an exception inside Recording.finish
    from coordinator.executor import InchwormExecutor, RunAborted  # noqa: PLC0415 - the run's imports, not the parser's
    from coordinator.localization import make_localizer  # noqa: PLC0415
    from coordinator.simulate import initial_estimate  # noqa: PLC0415
    from coordinator.strategies import make_strategy  # noqa: PLC0415
    from coordinator.zenoh_backend import AgentError, Timeouts, ZenohSwarmBackend  # noqa: PLC0415
    from runtime.models.trajectory import validate_connected  # noqa: PLC0415
    from runtime.wire.transport import open_session  # noqa: PLC0415
    from swarm_cli.estop import send_estop  # noqa: PLC0415
    from swarm_cli.summary import write_plots  # noqa: PLC0415

    cfg = model_config(args)
    traj = Trajectory.load(args.trajectory)
    validate_connected(traj, cfg.sensing_range_m)
    if not 2 <= args.min_robots <= traj.n:
        raise SwarmInputError(f"--min-robots {args.min_robots}: must be between 2 and the {traj.n} robots of the trajectory")
    selection = selection_config(args)
    strategy = make_strategy(args.method, traj.n, cfg, args.localizer, selection, args.seed)  # bad input fails before waiting
    settings = connection_settings(args)
    validate_run(args.run_id)
    recording = None
    if not args.no_record:
        path = args.record or default_recording(args.run_id)
        with signals.deferred():  # a signal now would leave the recorder thread with an unfinished file
            recording = Recording(settings, args.run_id, path, run_metadata(args, traj, cfg, selection),
                                  policy=args.on_record_error)
        print(f"coordinator: recording swarm/{args.run_id}/** to {path}", file=sys.stderr, flush=True)
    recorded, completed, result, status = None, False, None, 0
    try:
        if signals.received is not None:
            raise StopRequested(signals.received)
        with open_session(settings) as session, live_view(args, traj, session) as live:
            if recording is not None:
                recording.wait_subscribed(session)
            backend = ZenohSwarmBackend(session, args.run_id, traj.ids.tolist(), Timeouts(args.start_timeout, args.step_timeout),
                                        simulated=not args.no_truth)
            ended: BaseException | None = None
            partial = None
            try:
                backend.wait_for_agents()
                print(f"coordinator: {traj.n} agents alive, run {args.run_id}", file=sys.stderr, flush=True)
                progress = lambda done, total: print(f"coordinator: config {done}/{total} done (step {backend.step})", file=sys.stderr, flush=True)  # noqa: E731
                listener = backend if recording is None else _Checked(backend, recording.check)
                executor = InchwormExecutor(backend, make_localizer(args.localizer, cfg), strategy, cfg, progress, listener=listener,
                                            on_lost=args.on_lost, min_robots=args.min_robots)
                try:
                    result = executor.run(traj, initial_estimate(traj, args.seed, INITIAL_DELTA, INITIAL_HEADING_SIGMA))
                finally:
                    partial = executor.result  # the configurations completed, however the run ends
                completed = live.keep = True
            except (AgentError, RunAborted, RecordingStopped) as exc:
                ended = exc
                print(f"swarm coordinator: error: {exc}", file=sys.stderr, flush=True)
                result = getattr(exc, "result", None) or (partial if isinstance(exc, RecordingStopped) else None)
                status = EXIT_OUTPUT if isinstance(exc, RecordingStopped) else EXIT_AGENT
                if result is None:  # the agents did not come up: nothing ran
                    return status
            except BaseException as exc:
                ended = exc
                raise
            finally:
                with signals.deferred():
                    if not completed:  # whatever ended the run early: no robot may be left moving
                        send_estop(session, args.run_id, f"swarm coordinator (pid {os.getpid()})",
                                   f"the run ended early ({type(ended).__name__}: {ended})"[:2000])
                    backend.close()
    finally:
        if recording is not None:
            with signals.deferred():
                recorded = recording.finish(interrupted=signals.received is not None)
            if result is None:  # interrupted or failed run: the summary below is not printed
                print(recording_line(recorded) if recorded else f"recording failed: {recording.error}", flush=True)
    failed = recording is not None and recording.failed.is_set()
    if args.result:
        try:
            args.result.write_text(json.dumps(result_json(result)))
        except OSError as exc:
            failed = True
            print(f"swarm coordinator: error: cannot write --result {args.result}: {exc.strerror or exc}", file=sys.stderr, flush=True)
    plots = None
    if args.out and result.configs:
        try:
            plots = write_plots(result, args.out)
        except OSError as exc:
            failed = True
            print(f"swarm coordinator: error: cannot write the plots to {args.out}: {exc.strerror or exc}", file=sys.stderr, flush=True)
    print_summary(result, args, plots, recorded, None if recording is None else recording.error)
    live.linger(args.linger)
    return EXIT_OUTPUT if failed and status == 0 else status


def main(argv: list[str] | None = None) -> int:
    return run_standalone("swarm coordinator", add_arguments, run, argv)


if __name__ == "__main__":
    leave(main())  # no interpreter finalization under Zenoh threads (entry.leave)
