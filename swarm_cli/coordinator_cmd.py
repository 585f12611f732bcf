"""``swarm coordinator``: the coordinator process of a distributed run (``coordinator.node.process``).

    swarm coordinator --trajectory traj.json --run demo --hub tcp/127.0.0.1:7447 --seed 0 --method inchworm

Waits for every robot's agent, runs the same executor as ``swarm sim`` over Zenoh and prints
the per-configuration summary; with ``--out DIR`` it also writes ``trajectory.png`` (Fig.
13/14) and ``errors.png`` (Fig. 17, needs the simulated truth) there. Recording is on by
default (``recordings/<run>.mcap``); a recording that cannot be written is one line and follows
``--on-record-error continue`` (the run goes on unrecorded) or ``stop``. Whatever ends the run,
the summary, ``--json``, ``--result`` and the plots of the configurations completed are written.
``--standby`` / ``--resume RECORDING``: take the run over when its coordinator is gone
(``coordinator.node.process``, docs/failure-model.md); ``--rejoin no``: lost robots stay out.
Exit status: 0 done (also with lost robots), 3 the run was ended by lost robots (named) or the
agents did not come up, 4 another coordinator of the run is alive, 5 the recording, ``--result``
or a plot could not be written (or the run was stopped for its recording), 2 bad input,
128 + N after signal N (SIGINT, SIGTERM, SIGHUP).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path

from coordinator.strategies import METHODS
from inchworm.specs import CoordinatorSpec
from swarm_cli.entry import leave, portable_command, run_standalone
from swarm_cli.options import add_connection_options, add_simulation_options, model_config, selection_spec_of


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
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


def spec_of(args: argparse.Namespace) -> CoordinatorSpec:
    """The coordinator spec of the options."""
    text: Callable[[Path | None], str | None] = lambda path: None if path is None else str(path)  # noqa: E731
    return CoordinatorSpec(
        trajectory=str(args.trajectory), run_id=args.run_id, hub=args.hub, zenoh_config=args.zenoh_config, method=args.method,
        seed=args.seed, localizer=args.localizer, model=model_config(args), model_file=text(args.model),
        selection=selection_spec_of(args),
        start_timeout=args.start_timeout, step_timeout=args.step_timeout, on_lost=args.on_lost, min_robots=args.min_robots,
        truth=not args.no_truth, result=text(args.result), out=text(args.out), rejoin=args.rejoin == "yes", standby=args.standby,
        resume=text(args.resume), record=text(args.record), no_record=args.no_record, on_record_error=args.on_record_error,
        foxglove=args.foxglove, linger=args.linger, json=args.json, command=portable_command("swarm coordinator", sys.argv[1:]))


def run(args: argparse.Namespace) -> int:
    from inchworm.process_mains import run_coordinator  # noqa: PLC0415 - scipy and zenoh when it runs

    return run_coordinator(spec_of(args))


def main(argv: list[str] | None = None) -> int:
    return run_standalone("swarm coordinator", add_arguments, run, argv)


if __name__ == "__main__":
    leave(main())  # no interpreter finalization under Zenoh threads (entry.leave)
