"""``swarm agent``: the agent process of one robot, or of many, in a distributed run (simulated or gateway driver).

    swarm agent --id 3 --ids 0,1,2,3 --run demo --hub tcp/127.0.0.1:7447 --seed 0 --pose 0.1,0.2,1.57
    swarm agent --id 3 --ids 0,1,2,3 --run lab --hub tcp/127.0.0.1:7447 --driver gateway --gateway-config gw.json
    swarm agent --id 0-49 --trajectory traj.json --run demo --hub tcp/127.0.0.1:7447 --seed 0

``--id`` is this process's robot, or robots (``0-49``, ``0,2,5-9``): several are served
by one process on one Zenoh session (``robot_agent.host``), each still its own agent on
the wire. ``--ids`` lists every robot of the run (ranges too; default with
``--trajectory``: the trajectory's robots).
``--driver sim`` (default) simulates the robots in this process, starting from ``--pose``
(one robot) or from the initial poses of ``--trajectory``;
``--driver gateway`` drives the real or emulated robot through the link process of its
port (``swarm link``), with limits (drive, turn, workspace) and calibration from the
gateway config (docs/gateway.md); ``--driver package.module:Class`` (or ``file.py:Class``, or an
``inchworm_swarm.drivers`` entry point) builds a lab's own driver with ``--driver-option KEY=VALUE``
and times its calls with ``--command-timeout`` (docs/drivers.md). Exit status 3 when a robot was lost.

Connects as a Zenoh client to the hub, serves commands and observation requests until
SIGTERM/SIGINT (see ``robot_agent.agent``), then closes its session and exits 0.
``python -m swarm_cli.agent ...`` is the same command with a lighter start (the launcher uses it).
"""

from __future__ import annotations

import argparse
import logging
import math
import re
import sys
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from robot_agent.agent import READY_TIMEOUT_S, Agent
from robot_agent.driver import Driver, DriverContext, SimDriver
from robot_agent.plugins import BUILT_IN, build_driver, driver_class
from robot_agent.gateway_driver import GatewayDriver
from robot_agent.host import AgentHost
from runtime.errors import SwarmInputError
from runtime.gateway.config import GatewayConfig
from runtime.wire.keys import validate_run
from runtime.wire.messages import CommandLimits
from runtime.models.trajectory import Trajectory
from swarm_cli.entry import leave, on_stop_signals, run_standalone
from swarm_cli.options import add_connection_options, add_model_options, connection_settings, model_config, parse_list, positive

PLUGIN_COMMAND_TIMEOUT_S = 30.0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("agent", help="run the agent process of one robot, or of many (--id 0-49), in a distributed run")
    add_arguments(p)
    p.set_defaults(run=run)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--id", required=True, help="this process's robot id, or ids and ranges for one process hosting many (e.g. 0-49)")
    p.add_argument("--ids", help="every robot id of the run, comma-separated, ranges allowed (e.g. 0,1,2 or 0-499); "
                                 "default with --trajectory: its robots")
    p.add_argument("--trajectory", type=Path, help="trajectory JSON (docs/trajectory.md): the initial poses of simulated robots")
    p.add_argument("--run", dest="run_id", required=True, help="run id (the key space swarm/<run>/...)")
    add_connection_options(p)
    p.add_argument("--seed", type=int, default=0, help="seed of the run (motion and sensing noise; default 0)")
    p.add_argument("--driver", default="sim", metavar="DRIVER",
                   help="sim (simulated robot, default), gateway (a robot behind a link process), or a lab's own driver: "
                        "package.module:Class, file.py:Class or an inchworm_swarm.drivers entry point name (docs/drivers.md)")
    p.add_argument("--driver-option", action="append", default=[], metavar="KEY=VALUE",
                   help="an option for a lab's own driver (its DriverContext.options), repeatable")
    p.add_argument("--command-timeout", type=positive, default=None, metavar="S",
                   help=f"a lab's own driver must finish each command and observation within this many seconds, else the robot "
                        f"is stopped and reported lost (default {PLUGIN_COMMAND_TIMEOUT_S:g}; not applied to sim and gateway unless given)")
    p.add_argument("--gateway-config", type=Path, help="gateway config JSON (docs/gateway.md), required with --driver gateway")
    p.add_argument("--ready-timeout", type=float, default=READY_TIMEOUT_S,
                   help=f"seconds to wait for the robot's link process before declaring this agent alive (default {READY_TIMEOUT_S:g})")
    p.add_argument("--pose", help="initial true pose x,y,heading (m, m, rad) of one simulated robot (or give --trajectory)")
    p.add_argument("--motion-time", type=float, default=0.0, help="seconds a simulated motion takes (default 0)")
    p.add_argument("--max-drive", type=float, default=CommandLimits().max_drive_m, help="refuse drives longer than this (m, default 1)")
    p.add_argument("--max-turn-deg", type=float, default=math.degrees(CommandLimits().max_turn_rad), help="refuse turns larger than this (default 180)")
    add_model_options(p)


def parse_ids(text: str, option: str) -> list[int]:
    """Robot ids of an option such as ``--id 0-49`` or ``--ids 0,2,5-9`` (ranges inclusive), in the order given."""
    ids: list[int] = []
    for part in (p.strip() for p in str(text).split(",")):
        match = re.fullmatch(r"(\d+)(?:-(\d+))?", part)
        if match is None or (match[2] is not None and int(match[2]) < int(match[1])):
            raise SwarmInputError(f"{option} must be robot ids >= 0 and ranges a-b with a <= b, comma-separated (e.g. 0-49), got {text!r}")
        ids.extend(range(int(match[1]), int(match[2] or match[1]) + 1))
    if len(set(ids)) != len(ids):
        raise SwarmInputError(f"{option} names a robot twice: {text!r}")
    return ids


def format_ids(ids: Iterable[int]) -> str:
    """The shortest ``parse_ids`` text of ``ids`` (runs of consecutive ids as ranges): [0, 1, 2, 5] -> ``0-2,5``."""
    parts: list[str] = []
    for i in ids:
        i = int(i)
        if parts and parts[-1][1] == i - 1:
            parts[-1][1] = i
        else:
            parts.append([i, i])
    return ",".join(str(a) if a == b else f"{a}-{b}" for a, b in parts)


def driver_options(pairs: list[str]) -> dict[str, str]:
    """``--driver-option KEY=VALUE`` pairs as a dict (a key given twice: the last value)."""
    out = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or not key.strip():
            raise SwarmInputError(f"--driver-option must be KEY=VALUE, got {pair!r}")
        out[key.strip()] = value
    return out


def initial_pose(args: argparse.Namespace) -> list[float] | None:
    """``--pose`` as x, y, heading, or None."""
    if args.pose is None:
        return None
    pose = parse_list(args.pose, "--pose", float, minimum=-math.inf)
    if len(pose) != 3:
        raise SwarmInputError(f"--pose must be x,y,heading, got {args.pose!r}")
    return pose


def make_driver(args: argparse.Namespace, robot: int, ids: list[int], pose=None, gateway: GatewayConfig | None = None,
                plugin: type[Driver] | None = None) -> tuple[Driver, CommandLimits]:
    """The driver and limits of ``robot`` the options ask for (``pose``: its initial true pose, if known;
    ``plugin``: the class of ``--driver package.module:Class``)."""
    if args.driver == "gateway":
        if gateway is None:
            if args.gateway_config is None:
                raise SwarmInputError("--driver gateway needs --gateway-config FILE (docs/gateway.md)")
            gateway = GatewayConfig.load(args.gateway_config)
        port = gateway.port_of(robot)  # the robot must be behind a port of this gateway
        lim = gateway.limits
        limits = CommandLimits(max_drive_m=lim.max_drive_m, max_turn_rad=lim.max_turn_rad, workspace=lim.workspace)
        return GatewayDriver(args.run_id, robot, gateway.calibration_of(robot), gateway.timing, port.name), limits
    if pose is None:
        pose = initial_pose(args)
    limits = CommandLimits(max_drive_m=args.max_drive, max_turn_rad=math.radians(args.max_turn_deg))
    if args.driver != "sim":
        cls = plugin or driver_class(args.driver)
        context = DriverContext(robot=int(robot), ids=tuple(int(i) for i in ids), run=args.run_id, seed=args.seed,
                                pose=None if pose is None else np.array(pose, dtype=float), model=model_config(args),
                                options=driver_options(args.driver_option))
        return build_driver(args.driver, cls, context), limits
    if pose is None:
        raise SwarmInputError("--driver sim needs --pose x,y,heading (the simulated robot's initial true pose) or --trajectory FILE")
    return SimDriver(robot, ids, pose, model_config(args), args.seed, args.motion_time), limits


def make_agents(args: argparse.Namespace) -> list[Agent]:
    """The agents of ``--id`` (robots of ``--ids``), each with its own driver; options checked first."""
    settings = connection_settings(args)
    validate_run(args.run_id)
    plugin = None if args.driver in BUILT_IN else driver_class(args.driver)
    driver_options(args.driver_option)
    hosted = parse_ids(args.id, "--id")
    traj = Trajectory.load(args.trajectory) if args.trajectory else None
    if args.ids is not None:
        ids = parse_ids(args.ids, "--ids")
    elif traj is not None:
        ids = [int(i) for i in traj.ids]
    else:
        raise SwarmInputError("give --ids (every robot of the run, e.g. 0-9) or --trajectory FILE")
    outside = sorted(set(hosted) - set(ids))
    if outside:
        raise SwarmInputError(f"--id names robots {outside} that are not robots of the run (--ids {args.ids or format_ids(ids)})")
    poses: dict[int, object] = {}
    if args.driver != "gateway" and args.pose is None and traj is not None:
        missing = sorted(set(hosted) - {int(i) for i in traj.ids})
        if missing and args.driver == "sim":
            raise SwarmInputError(f"--id names robots {missing} that {args.trajectory} does not have")
        poses = {int(i): p for i, p in zip(traj.ids, traj.initial_poses)}
    elif len(hosted) > 1 and (args.driver == "sim" or (args.driver != "gateway" and args.pose is not None)):
        raise SwarmInputError(f"--pose is one robot's pose: give --trajectory FILE for the initial poses of --id {args.id}")
    gateway = None
    if args.driver == "gateway":
        if args.gateway_config is None:
            raise SwarmInputError("--driver gateway needs --gateway-config FILE (docs/gateway.md)")
        gateway = GatewayConfig.load(args.gateway_config)
    timeout = args.command_timeout if args.command_timeout is not None or plugin is None else PLUGIN_COMMAND_TIMEOUT_S
    agents = []
    for robot in hosted:
        driver, limits = make_driver(args, robot, ids, poses.get(robot), gateway, plugin)
        agents.append(Agent(settings, args.run_id, robot, ids, driver, limits, args.ready_timeout, timeout))
    return agents


def run(args: argparse.Namespace) -> int:
    agents = make_agents(args)
    logging.basicConfig(level=logging.WARNING, format=f"agent {args.id}: %(levelname)s %(message)s", stream=sys.stderr)
    server = agents[0] if len(agents) == 1 else AgentHost(agents[0].settings, agents)
    on_stop_signals(server.stop)
    return server.run()


def main(argv: list[str] | None = None) -> int:
    return run_standalone("swarm agent", add_arguments, run, argv)


if __name__ == "__main__":
    leave(main())  # no interpreter finalization under Zenoh threads (entry.leave)
