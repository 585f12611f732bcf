"""``swarm coordinator``: the coordinator process of a distributed run (``coordinator.process``).

    swarm coordinator --trajectory traj.json --run demo --hub tcp/127.0.0.1:7447 --seed 0 --method inchworm

Waits for every robot's agent, runs the same executor as ``swarm sim`` over Zenoh and prints
the per-configuration summary; with ``--out DIR`` it also writes ``trajectory.png`` (Fig.
13/14) and ``errors.png`` (Fig. 17, needs the simulated truth) there. Recording is on by
default (``recordings/<run>.mcap``); a recording that cannot be written is one line and follows
``--on-record-error continue`` (the run goes on unrecorded) or ``stop``. Whatever ends the run,
the summary, ``--json``, ``--result`` and the plots of the configurations completed are written.
``--standby`` / ``--resume RECORDING``: take the run over when its coordinator is gone
(``coordinator.process``, docs/failure-model.md); ``--rejoin no``: lost robots stay out.
Exit status: 0 done (also with lost robots), 3 the run was ended by lost robots (named) or the
agents did not come up, 4 another coordinator of the run is alive, 5 the recording, ``--result``
or a plot could not be written (or the run was stopped for its recording), 2 bad input,
128 + N after signal N (SIGINT, SIGTERM, SIGHUP).
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from coordinator.strategies import METHODS
from runtime.models.trajectory import Trajectory
from swarm_cli.entry import EXIT_OUTPUT, EXIT_RUN, exit_code, leave, portable_command, run_standalone
from swarm_cli.options import (
    add_connection_options,
    add_simulation_options,
    connection_label,
    connection_settings,
    model_config,
    print_json,
    selection_config,
)


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
    p.add_argument("--rejoin", choices=("yes", "no"), default="yes",
                   help="a lost robot whose agent comes back rejoins at the next configuration (default yes)")
    takeover = p.add_mutually_exclusive_group()
    takeover.add_argument("--standby", action="store_true",
                          help="follow the run's live coordinator and take the run over from its last checkpoint if it dies "
                               "(same options as the coordinator it stands by for)")
    takeover.add_argument("--resume", type=Path, default=None, metavar="RECORDING",
                          help="take over the run from the last checkpoint in this MCAP recording (its coordinator is gone)")
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


def run(args: argparse.Namespace) -> int:
    logging.basicConfig(level=logging.WARNING, format="coordinator: %(levelname)s %(message)s", stream=sys.stderr)
    from coordinator.stop import StopSignals  # noqa: PLC0415

    signals = StopSignals()  # SIGINT/SIGTERM end the run; never an exception inside the recording's finish
    from coordinator.process import CoordinatorOptions, default_recording, recording_line, run_coordinator, say  # noqa: PLC0415
    from inchworm.simulation import run_json, summary_text, write_run_outputs  # noqa: PLC0415

    options = CoordinatorOptions(
        Trajectory.load(args.trajectory), args.run_id, connection_settings(args), connection_label(args), args.method, args.seed,
        args.localizer, model_config(args), args.model, selection_config(args), args.start_timeout, args.step_timeout, args.on_lost, args.min_robots,
        truth=not args.no_truth,
        record=None if args.no_record else args.record or default_recording(args.run_id,
                                                                             "standby" if args.standby else "resume" if args.resume else ""),
        foxglove_port=args.foxglove, command=portable_command("swarm coordinator", sys.argv[1:]), on_record_error=args.on_record_error,
        standby=args.standby, resume=args.resume, rejoin=args.rejoin == "yes")
    outcome = run_coordinator(options, signals, lambda done, total, step: say(f"config {done}/{total} done (step {step})"))
    status = 0
    if outcome.error is not None:  # another coordinator holds the run (4), lost or stopped (3), the recording stopped it (5)
        print(f"swarm coordinator: error: {outcome.error}", file=sys.stderr, flush=True)
        status = exit_code(outcome.error) or EXIT_RUN
        if outcome.result is None:  # nothing ran (the agents did not come up, another coordinator holds the run)
            return status
    if outcome.result is None:  # a standby whose run finished without it
        return EXIT_OUTPUT if outcome.recording_error is not None else 0
    result = outcome.result
    plots, errors = write_run_outputs(result, args.result, args.out)
    for line in errors:
        print(f"swarm coordinator: error: {line}", file=sys.stderr, flush=True)
    failed = outcome.recording_error is not None or bool(errors)
    radius = options.model.robot_radius_m
    print(summary_text(result, args.method, args.localizer, radius))
    if plots:
        print(f"wrote {', '.join(plots)}")
    if outcome.recording:
        print(recording_line(outcome.recording))
    elif outcome.recording_error is not None:
        print(f"recording failed: {outcome.recording_error}")
    if args.json:
        print_json(run_json(result, args.method, args.localizer, args.seed, plots, outcome.recording["path"] if outcome.recording else None,
                            radius, None if outcome.error is None else str(outcome.error)))
    outcome.live.linger(args.linger)
    return EXIT_OUTPUT if failed and status == 0 else status


def main(argv: list[str] | None = None) -> int:
    return run_standalone("swarm coordinator", add_arguments, run, argv)


if __name__ == "__main__":
    leave(main())  # no interpreter finalization under Zenoh threads (entry.leave)
