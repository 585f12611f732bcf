"""``swarm agent``: one robot's agent process in a distributed run, with a simulated or gateway driver.

    swarm agent --id 3 --ids 0,1,2,3 --run demo --hub tcp/127.0.0.1:7447 --seed 0 --pose 0.1,0.2,1.57
    swarm agent --id 3 --ids 0,1,2,3 --run lab --hub tcp/127.0.0.1:7447 --driver gateway --gateway-config gw.json

``--driver sim`` (default) simulates the robot in this process (``--pose`` required);
``--driver gateway`` drives the real or emulated robot through the link process of its
port (``swarm link``), with limits (drive, turn, workspace) and calibration from the
gateway config (docs/gateway.md). Exit status 3 when the robot was lost.

Connects as a Zenoh client to the hub, serves commands and observation requests until
SIGTERM/SIGINT (see ``robot_agent.agent``), then closes its session and exits 0.
``python -m swarm_cli.agent ...`` is the same command with a lighter start (the launcher uses it).
"""

from __future__ import annotations

import argparse
import logging
import math
import signal
import sys
from pathlib import Path

from robot_agent.agent import READY_TIMEOUT_S, Agent
from robot_agent.driver import Driver, SimDriver
from robot_agent.gateway_driver import GatewayDriver
from runtime.errors import SwarmInputError
from runtime.gateway_config import GatewayConfig
from runtime.keys import validate_run
from runtime.messages import CommandLimits
from swarm_cli.entry import run_standalone
from swarm_cli.options import add_connection_options, add_model_options, connection_settings, model_config, parse_list


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("agent", help="run one robot's agent process (simulated driver) of a distributed run")
    add_arguments(p)
    p.set_defaults(run=run)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--id", type=int, required=True, help="this robot's id")
    p.add_argument("--ids", required=True, help="every robot id of the run, comma-separated (e.g. 0,1,2)")
    p.add_argument("--run", dest="run_id", required=True, help="run id (the key space swarm/<run>/...)")
    add_connection_options(p)
    p.add_argument("--seed", type=int, default=0, help="seed of the run (motion and sensing noise; default 0)")
    p.add_argument("--driver", choices=("sim", "gateway"), default="sim", help="simulated robot, or a robot behind a link process (default sim)")
    p.add_argument("--gateway-config", type=Path, help="gateway config JSON (docs/gateway.md), required with --driver gateway")
    p.add_argument("--ready-timeout", type=float, default=READY_TIMEOUT_S,
                   help=f"seconds to wait for the robot's link process before declaring this agent alive (default {READY_TIMEOUT_S:g})")
    p.add_argument("--pose", help="initial true pose x,y,heading (m, m, rad), required with --driver sim")
    p.add_argument("--motion-time", type=float, default=0.0, help="seconds a simulated motion takes (default 0)")
    p.add_argument("--max-drive", type=float, default=CommandLimits().max_drive_m, help="refuse drives longer than this (m, default 1)")
    p.add_argument("--max-turn-deg", type=float, default=math.degrees(CommandLimits().max_turn_rad), help="refuse turns larger than this (default 180)")
    add_model_options(p)


def make_driver(args: argparse.Namespace, ids: list[int]) -> tuple[Driver, CommandLimits]:
    """The driver and limits the options ask for."""
    if args.driver == "gateway":
        if args.gateway_config is None:
            raise SwarmInputError("--driver gateway needs --gateway-config FILE (docs/gateway.md)")
        gateway = GatewayConfig.load(args.gateway_config)
        port = gateway.port_of(args.id)  # the robot must be behind a port of this gateway
        lim = gateway.limits
        limits = CommandLimits(max_drive_m=lim.max_drive_m, max_turn_rad=lim.max_turn_rad, workspace=lim.workspace)
        return GatewayDriver(args.run_id, args.id, gateway.calibration_of(args.id), gateway.timing, port.name), limits
    if args.pose is None:
        raise SwarmInputError("--driver sim needs --pose x,y,heading (the simulated robot's initial true pose)")
    pose = parse_list(args.pose, "--pose", float, minimum=-math.inf)
    if len(pose) != 3:
        raise SwarmInputError(f"--pose must be x,y,heading, got {args.pose!r}")
    limits = CommandLimits(max_drive_m=args.max_drive, max_turn_rad=math.radians(args.max_turn_deg))
    return SimDriver(args.id, ids, pose, model_config(args), args.seed, args.motion_time), limits


def run(args: argparse.Namespace) -> int:
    ids = parse_list(args.ids, "--ids")
    logging.basicConfig(level=logging.WARNING, format=f"agent {args.id}: %(levelname)s %(message)s", stream=sys.stderr)
    settings = connection_settings(args)
    validate_run(args.run_id)
    driver, limits = make_driver(args, ids)
    agent = Agent(settings, args.run_id, args.id, ids, driver, limits, args.ready_timeout)
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: agent.stop())
    return agent.run()


def main(argv: list[str] | None = None) -> int:
    return run_standalone("swarm agent", add_arguments, run, argv)


if __name__ == "__main__":
    sys.exit(main())
