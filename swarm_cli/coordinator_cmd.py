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

from inchworm.specs import CoordinatorSpec
from swarm_cli.entry import leave, portable_command, run_standalone
from swarm_cli.options import add_connection_options, add_simulation_options, connection_of, model_config, selection_spec_of
from swarm_cli.schema import add_fields, options_of


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("coordinator", help="run the coordinator of a distributed run (agents started separately)")
    add_arguments(p)
    p.set_defaults(run=run)


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_fields(p, CoordinatorSpec, only=("trajectory", "run_id"))
    add_connection_options(p)
    add_fields(p, CoordinatorSpec, only=("method", "seed", "start_timeout", "step_timeout", "on_lost", "min_robots", "truth", "result", "out"))
    p.add_argument("--rejoin", choices=("yes", "no"), default="yes",
                   help="a lost robot whose agent comes back rejoins at the next configuration (default yes)")
    add_fields(p.add_mutually_exclusive_group(), CoordinatorSpec, only=("standby", "resume"))
    add_record_options(p)
    add_simulation_options(p)


def add_record_options(p: argparse.ArgumentParser) -> None:
    """``--record PATH`` or ``--no-record``, ``--on-record-error``, ``--foxglove [PORT]``, ``--linger`` (``swarm launch`` too)."""
    add_fields(p.add_mutually_exclusive_group(), CoordinatorSpec, only=("record", "no_record"))
    add_fields(p, CoordinatorSpec, only=("on_record_error", "foxglove", "linger"))


def spec_of(args: argparse.Namespace) -> CoordinatorSpec:
    """The coordinator spec of the options."""
    return options_of(args, CoordinatorSpec, **connection_of(args), localizer=args.localizer, model=model_config(args),
                      model_file=None if args.model is None else str(args.model), selection=selection_spec_of(args),
                      rejoin=args.rejoin == "yes", json=args.json, command=portable_command("swarm coordinator", sys.argv[1:]))


def run(args: argparse.Namespace) -> int:
    from inchworm.process_mains import run_coordinator  # noqa: PLC0415 - scipy and zenoh when it runs

    return run_coordinator(spec_of(args))


def main(argv: list[str] | None = None) -> int:
    return run_standalone("swarm coordinator", add_arguments, run, argv)


if __name__ == "__main__":
    leave(main())  # no interpreter finalization under Zenoh threads (entry.leave)
