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

import numpy as np

from runtime.errors import SwarmInputError
from runtime.models.config import ModelConfig
from runtime.models.trajectory import Trajectory, random_trajectory, validate_connected
from swarm_cli.options import add_json_option, positive, print_json


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("trajectory", help="write a random trajectory file (new) or check one (check)")
    inner = p.add_subparsers(dest="action", required=True, metavar="ACTION")
    new = inner.add_parser("new", help="write a random trajectory (the one swarm sim would make for these options)")
    new.add_argument("file", type=Path, help="trajectory JSON file to write")
    new.add_argument("--robots", type=int, default=10, help="robots (default 10)")
    new.add_argument("--configs", type=int, default=5, help="desired configurations (default 5)")
    new.add_argument("--seed", type=int, default=0, help="seed of the random trajectory (default 0)")
    new.add_argument("--step", type=positive, default=0.3, help="how far the swarm moves per configuration, m (default 0.3)")
    check = inner.add_parser("check", help="check a trajectory file: format, robots, connectivity within the sensing range")
    check.add_argument("file", type=Path, help="trajectory JSON file (docs/trajectory.md)")
    for q in (new, check):
        q.add_argument("--sensing-range", type=positive, default=ModelConfig().sensing_range_m,
                       help="sensing range in m every configuration must stay connected within (default 0.5)")
        add_json_option(q)
    new.set_defaults(run=run_new)
    check.set_defaults(run=run_check)


def _report(verb: str, path: Path, summary: dict[str, float], as_json: bool) -> int:
    print(f"{verb} {path}: {summary['robots']} robots, {summary['configs']} configurations, connected within "
          f"{summary['sensing_range_m']:g} m; robots move {summary['move_mean_m']:.3f} m per configuration on average "
          f"(at most {summary['move_max_m']:.3f} m)", flush=True)
    if as_json:
        print_json({"file": str(path), **summary})
    return 0


def run_new(args: argparse.Namespace) -> int:
    traj = random_trajectory(args.robots, args.configs, np.random.default_rng(args.seed), sensing_range=args.sensing_range, step=args.step)
    args.file.parent.mkdir(parents=True, exist_ok=True)
    traj.save(args.file)
    return _report("wrote", args.file, traj.describe(args.sensing_range), args.json)


def run_check(args: argparse.Namespace) -> int:
    traj = Trajectory.load(args.file)
    try:
        validate_connected(traj, args.sensing_range)
    except SwarmInputError as exc:
        raise SwarmInputError(f"trajectory {args.file}: {exc}") from None
    return _report("ok", args.file, traj.describe(args.sensing_range), args.json)
