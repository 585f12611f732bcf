"""Entry point of the ``swarm`` command.

Subcommands are listed here by name, module and one-line help; only the module of the
command being run is imported (``swarm_cli.entry.add_commands``), so ``swarm --help`` and
``swarm X --help`` do not pay for matplotlib, scipy or zenoh.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable

from swarm_cli.entry import Command, OneLineParser, add_commands, guarded, leave, limit_blas_threads
from swarm_cli.options import apply_config, check_limits
from swarm_cli.version import VersionAction

COMMANDS = (
    Command("sim", "swarm_cli.sim", "simulate one run along a trajectory and plot it"),
    Command("compare", "swarm_cli.compare", "Table I/II: P_f of every method on the same random trajectories"),
    Command("study", "swarm_cli.study", "parameter studies (anchors: Fig. 4/5 and Appendix A; noise: where anchors pay off; "
                                        "selection: search vs optimum; calibration: the paper's noise; consistency: NEES)"),
    Command("trajectory", "swarm_cli.trajectory_cmd", "write a random trajectory file (new) or check one (check)"),
    Command("localize", "swarm_cli.localize", "localize robots from range/bearing observations in a JSON file"),
    Command("bench", "swarm_cli.bench", "benchmarks (print numbers; --json for machines)"),
    Command("agent", "swarm_cli.agent", "run the agent process of one robot, or of many (--id 0-49), in a distributed run"),
    Command("coordinator", "swarm_cli.coordinator_cmd", "run the coordinator of a distributed run (agents started separately)"),
    Command("launch", "swarm_cli.launch", "run agents + coordinator as processes on this host (Zenoh on loopback)"),
    Command("demo", "swarm_cli.launch", "a distributed run of 10 agent processes on a small built-in trajectory"),
    Command("record", "swarm_cli.record", "record every message of a run to an MCAP file until Ctrl-C / SIGTERM"),
    Command("info", "swarm_cli.info", "channels, counts, duration, metadata and bad messages of an MCAP recording"),
    Command("recover", "swarm_cli.recover", "rewrite an unfinished MCAP recording as a finished, indexed file"),
    Command("replay", "swarm_cli.replay", "re-publish a recording on Zenoh (--publish) or check that it is reproduced (--check)"),
    Command("export", "swarm_cli.export", "convert a recording for other tools (--ros2: a rosbag2 with standard ROS 2 messages)"),
    Command("calibrate", "swarm_cli.calibrate", "fit the noise model (motion, sensing) to a recorded run and a tracker's true poses"),
    Command("plot", "swarm_cli.plot", "the trajectory and error plots of swarm sim, from a recording"),
    Command("link", "swarm_cli.link", "own one serial/radio port of the gateway and bridge its robots to their agents"),
    Command("estop", "swarm_cli.estop", "emergency stop: every robot of the run stops now (latched)"),
    Command("router", "swarm_cli.router", "run the Zenoh router of a multi-host swarm until Ctrl-C / SIGTERM"),
    Command("certs", "swarm_cli.certs", "create a lab CA and per-host TLS certificates (mutual TLS, see deploy/README.md)"),
    Command("ros2", "swarm_cli.ros2", "simulated ROS 2 robots (robots), a run live in ROS 2 (bridge); extra ros2"),
    Command("emulate-robots", "swarm_cli.emulate", "emulate the robots of a gateway config on pseudo-terminals (frame protocol)"),
)


def build_parser(argv: list[str] | None = None) -> argparse.ArgumentParser:
    """The ``swarm`` parser; with ``argv``, only the command it names is fully registered (and imported),
    without it every command is (for tests and tools that walk the parser)."""
    parser = OneLineParser(prog="swarm", description="Inchworm swarm runtime: simulation, localization, benchmarks.")
    parser.add_argument("--version", action=VersionAction)
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    add_commands(sub, COMMANDS, argv or [], full=argv is None)
    return parser


ZENOH_PROCESSES = ("agent", "coordinator", "ros2")  # long-lived processes whose exit skips finalization (entry.leave)


def parse(argv: list[str]) -> argparse.Namespace:
    """The command line; a study's ``--config FILE`` gives the defaults of its options, the flags override them."""
    parser = build_parser(argv)
    args = _parsed(parser, argv)
    if getattr(args, "_study_parser", None) is not None and args.config is not None:
        code = guarded("swarm", lambda: apply_config(args._study_parser, args.config))
        if code:
            sys.exit(code)
        args = _parsed(parser, argv)
    return args


def _parsed(parser: argparse.ArgumentParser, argv: list[str]) -> argparse.Namespace:
    """``parser.parse_args(argv)``, but arguments no command takes are the error of the command they were given to
    (``swarm sim: error: unrecognized arguments: -n 3 (see swarm sim --help)``), not of ``swarm``."""
    args, extra = parser.parse_known_args(argv)
    if extra:
        _chosen(parser, args).error(f"unrecognized arguments: {' '.join(extra)}")
    return args


def _chosen(parser: argparse.ArgumentParser, args: argparse.Namespace) -> argparse.ArgumentParser:
    """The (sub)command parser ``args`` were parsed by: the parser of each chosen subcommand, down to the last."""
    while True:
        subs = next((a for a in parser._actions if isinstance(a, argparse._SubParsersAction)), None)
        name = None if subs is None else getattr(args, subs.dest, None)
        if subs is None or name not in subs.choices:
            return parser
        parser = subs.choices[name]


def main(argv: list[str] | None = None) -> int:
    standalone = argv is None
    argv = sys.argv[1:] if argv is None else list(argv)
    limit_blas_threads()
    args = parse(argv)

    def checked_run() -> int | None:
        check_limits(args)
        run: Callable[[argparse.Namespace], int | None] = args.run  # the command's ``run(args)``
        return run(args)

    code = guarded(f"swarm {args.command}", checked_run)
    if standalone and args.command in ZENOH_PROCESSES:
        leave(code)
    return code


if __name__ == "__main__":
    sys.exit(main())
