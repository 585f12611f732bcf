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

from inchworm.specs import EmulatorSpec
from runtime.errors import SwarmInputError
from swarm_cli.entry import run_standalone
from swarm_cli.options import add_connection_options, add_model_options, connection_of, model_config, nonnegative, parse_list
from swarm_cli.schema import add_fields, options_of

PROG = "swarm emulate-robots"


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("emulate-robots", help="emulate the robots of a gateway config on pseudo-terminals (frame protocol)")
    add_arguments(p)
    p.set_defaults(run=run)


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The flags of ``EmulatorSpec``'s fields, and apart the frame indices and the blackout (parsed) and the model."""
    add_fields(p, EmulatorSpec, only=("config", "trajectory", "seed", "motion_time", "miscalibrate"))
    add_model_options(p)
    add_fields(p.add_argument_group("physical world (docs/physics.md)"), EmulatorSpec, only=("physics", "physics_params", "physics_speed"),
               types={"physics_speed": nonnegative})
    g = p.add_argument_group("fault injection (per port; rx = frames from the gateway, tx = frames to it)")
    add_fields(g, EmulatorSpec, only=("drop", "corrupt", "delay"))
    g.add_argument("--drop-rx", default="", metavar="I,J", help="0-based indices of received frames to drop (e.g. 0,5)")
    g.add_argument("--drop-tx", default="", metavar="I,J", help="0-based indices of sent frames to drop (e.g. 0 = the first answer)")
    g.add_argument("--blackout", default=None, metavar="STEP:SECONDS",
                   help="the radio goes dead both ways for SECONDS when a robot accepts the command of STEP (e.g. 2:1.0)")
    add_fields(p, EmulatorSpec, only=("events", "write_config"))
    add_connection_options(p, required=False)
    add_fields(p, EmulatorSpec, only=("run_id", "json"))


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

    return run_emulator(spec_of(args))


def spec_of(args: argparse.Namespace) -> EmulatorSpec:
    """The emulator spec of the flags."""
    return options_of(args, EmulatorSpec, **connection_of(args), model=model_config(args), drop_rx=_indices(args.drop_rx, "--drop-rx"),
                      drop_tx=_indices(args.drop_tx, "--drop-tx"), blackout=_blackout(args.blackout))


def main(argv: list[str] | None = None) -> int:
    return run_standalone(PROG, add_arguments, run, argv)


if __name__ == "__main__":
    sys.exit(main())
