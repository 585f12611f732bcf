"""``swarm emulate-robots``: the robots of a gateway config, emulated on pseudo-terminals (docs/emulator.md).

    swarm emulate-robots --config deploy/gateway.example.json --trajectory traj.json \\
        --write-config out/gateway.pty.json [--events events.jsonl] [--hub tcp/127.0.0.1:7447 --run demo]

One ``robot_agent.emulator.PortEmulator`` per port of the config, all in one
``EmulatedWorld`` built from the trajectory's initial poses (every robot of the config must
be in the trajectory; ``robot_agent.emulator_process``). Writes the config with the pty device
paths to ``--write-config`` (atomically, once the ptys are ready, so a launcher can wait for
the file), then prints ``port NAME: DEVICE (robots 0,1,2)`` per port and, with ``--json``, one
line ``{"ports": {name: device}, "config": OUT}``. Serves until SIGTERM/SIGINT, then closes
everything and exits 0 (2 on bad input). ``python -m swarm_cli.emulate`` is the same.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable
from pathlib import Path

from inchworm.specs import EmulatorSpec
from runtime.errors import SwarmInputError
from swarm_cli.entry import run_standalone
from swarm_cli.options import add_connection_options, add_model_options, model_config, nonnegative, parse_list

PROG = "swarm emulate-robots"


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("emulate-robots", help="emulate the robots of a gateway config on pseudo-terminals (frame protocol)")
    add_arguments(p)
    p.set_defaults(run=run)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", type=Path, required=True, help="gateway config JSON: its ports and robots are emulated (docs/gateway.md)")
    p.add_argument("--trajectory", type=Path, required=True, help="trajectory JSON: the robots' initial true poses (docs/trajectory.md)")
    p.add_argument("--seed", type=int, default=0, help="seed of the run: motion and sensing noise as simulated agents, and random faults (default 0)")
    p.add_argument("--motion-time", type=float, default=0.0, help="seconds a motion takes; it is applied at its end (default 0)")
    p.add_argument("--miscalibrate", action="store_true",
                   help="give each robot the config's calibration as true deviations (drive x motion_scale, range + bias, bearing + offset)")
    add_model_options(p)
    w = p.add_argument_group("physical world (docs/physics.md)")
    w.add_argument("--physics", action="store_true",
                   help="the robots drive in a rigid-body world (they collide, push, stall; sensing with occlusion) instead of the "
                        "noise model; needs pip install 'inchworm-swarm[physics]'")
    w.add_argument("--physics-param", action="append", default=[], metavar="NAME=VALUE",
                   help="with --physics: a parameter of the world (runtime.world.params.PhysicsParams), repeatable")
    w.add_argument("--physics-speed", type=nonnegative, default=0.0, metavar="X",
                   help="with --physics: world seconds per wall-clock second (0: as fast as it computes, the default)")
    g = p.add_argument_group("fault injection (per port; rx = frames from the gateway, tx = frames to it)")
    g.add_argument("--drop", type=float, default=0.0, metavar="P", help="probability a frame is lost, both directions (default 0)")
    g.add_argument("--corrupt", type=float, default=0.0, metavar="P", help="probability one byte of an outgoing frame is flipped (default 0)")
    g.add_argument("--delay", type=float, default=0.0, metavar="S", help="seconds every outgoing frame is delayed (default 0)")
    g.add_argument("--drop-rx", default="", metavar="I,J", help="0-based indices of received frames to drop (e.g. 0,5)")
    g.add_argument("--drop-tx", default="", metavar="I,J", help="0-based indices of sent frames to drop (e.g. 0 = the first answer)")
    g.add_argument("--blackout", default=None, metavar="STEP:SECONDS",
                   help="the radio goes dead both ways for SECONDS when a robot accepts the command of STEP (e.g. 2:1.0)")
    p.add_argument("--events", type=Path, default=None, metavar="FILE", help="write every notable event as a JSON line (flushed per line)")
    p.add_argument("--write-config", type=Path, default=None, metavar="OUT", help="write the config with the pty device paths here, atomically")
    add_connection_options(p, required=False)
    p.add_argument("--run", dest="run_id", default=None, help="run id: with --hub/--zenoh-config, publish the true poses (TruthMessage)")
    p.add_argument("--json", action="store_true", help='print {"ports": {name: device}, "config": OUT} as one JSON line when ready')


def _blackout(text: str | None) -> tuple[int, float] | None:
    """``--blackout STEP:SECONDS`` -> (step, seconds), checked."""
    if text is None:
        return None
    step, sep, seconds = text.partition(":")
    try:
        value = (int(step), float(seconds))
    except ValueError:
        value = None
    if not sep or value is None or value[0] < 1 or not (math.isfinite(value[1]) and value[1] > 0):
        raise SwarmInputError(f"--blackout must be STEP:SECONDS with a step >= 1 and seconds > 0 (e.g. 2:1.0), got {text!r}")
    return value


def _indices(text: str, option: str) -> tuple[int, ...]:
    return tuple(sorted(set(parse_list(text, option)))) if text.strip() else ()


def run(args: argparse.Namespace) -> int:
    from inchworm.process_mains import run_emulator  # noqa: PLC0415 - the emulator when it runs

    text: Callable[[Path | None], str | None] = lambda path: None if path is None else str(path)  # noqa: E731
    return run_emulator(EmulatorSpec(
        config=str(args.config), trajectory=str(args.trajectory), seed=args.seed, motion_time=args.motion_time, miscalibrate=args.miscalibrate,
        model=model_config(args), physics=args.physics, physics_params=tuple(args.physics_param), physics_speed=args.physics_speed,
        drop=args.drop, corrupt=args.corrupt, delay=args.delay, drop_rx=_indices(args.drop_rx, "--drop-rx"),
        drop_tx=_indices(args.drop_tx, "--drop-tx"), blackout=_blackout(args.blackout), events=text(args.events),
        write_config=text(args.write_config), hub=args.hub, zenoh_config=args.zenoh_config, run_id=args.run_id, json=args.json))


def main(argv: list[str] | None = None) -> int:
    return run_standalone(PROG, add_arguments, run, argv)


if __name__ == "__main__":
    sys.exit(main())
