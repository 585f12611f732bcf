"""``swarm trajectory new|check``: write a random trajectory file, or check one (docs/trajectory.md).

    swarm trajectory new T.json [--robots 10] [--configs 5] [--seed 0] [--sensing-range 0.5] [--step 0.3]
    swarm trajectory check T.json [--sensing-range 0.5] [--json]

``new`` writes the random trajectory ``swarm sim`` / ``swarm launch`` would make for the same
options (Section 7: the swarm moved rigidly by ``--step`` m and reshaped at each configuration,
connected within 0.9 x the sensing range); ``check`` loads a file and checks what the runtime
will check before a run: the format (a bad row is named by its number and robot id) and that
every configuration, the initial one included, is connected within the sensing range. Both
print the robots, configurations and how far the robots move per configuration (m). Exit 0
when the file is usable, 2 (a one-line message) when it is not.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from inchworm.trajectory_files import CheckTrajectoryOptions, NewTrajectoryOptions, TrajectoryFile, check_trajectory, new_trajectory
from swarm_cli.options import add_json_option, positive, print_json
from swarm_cli.schema import add_fields, options_of

POSITIVE = {"step": positive, "sensing_range": positive}  # refused as typed, naming the flag


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("trajectory", help="write a random trajectory file (new) or check one (check)")
    inner = p.add_subparsers(dest="action", required=True, metavar="ACTION")
    new = inner.add_parser("new", help="write a random trajectory (the one swarm sim would make for these options)")
    new.add_argument("file", type=Path, help="trajectory JSON file to write")
    add_fields(new, NewTrajectoryOptions, exclude=("file",), types=POSITIVE)
    check = inner.add_parser("check", help="check a trajectory file: format, robots, connectivity within the sensing range")
    check.add_argument("file", type=Path, help="trajectory JSON file (docs/trajectory.md)")
    add_fields(check, CheckTrajectoryOptions, exclude=("file",), types=POSITIVE)
    for q in (new, check):
        add_json_option(q)
    new.set_defaults(run=run_new)
    check.set_defaults(run=run_check)


def new_options(args: argparse.Namespace) -> NewTrajectoryOptions:
    """``swarm trajectory new``'s options (the file: its positional)."""
    return options_of(args, NewTrajectoryOptions, file=args.file)


def check_options(args: argparse.Namespace) -> CheckTrajectoryOptions:
    """``swarm trajectory check``'s options (the file: its positional)."""
    return options_of(args, CheckTrajectoryOptions, file=args.file)


def _report(verb: str, done: TrajectoryFile, as_json: bool) -> int:
    summary = done.summary
    print(f"{verb} {done.file}: {summary['robots']} robots, {summary['configs']} configurations, connected within "
          f"{summary['sensing_range_m']:g} m; robots move {summary['move_mean_m']:.3f} m per configuration on average "
          f"(at most {summary['move_max_m']:.3f} m)", flush=True)
    if as_json:
        print_json(done.to_json())
    return 0


def run_new(args: argparse.Namespace) -> int:
    return _report("wrote", new_trajectory(new_options(args)), args.json)


def run_check(args: argparse.Namespace) -> int:
    return _report("ok", check_trajectory(check_options(args)), args.json)
