"""``swarm agent``: the agent process of one robot, or of many, in a distributed run (simulated or gateway driver).

    swarm agent --id 3 --ids 0,1,2,3 --run demo --hub tcp/127.0.0.1:7447 --seed 0 --pose 0.1,0.2,1.57
    swarm agent --id 3 --ids 0,1,2,3 --run lab --hub tcp/127.0.0.1:7447 --driver gateway --gateway-config gw.json
    swarm agent --id 0-49 --trajectory traj.json --run demo --hub tcp/127.0.0.1:7447 --seed 0
    swarm agent --id 0-4 --ids 0-9 --run lab --hub tcp/127.0.0.1:7447 --driver gateway --gateway-config gw.json --link
    swarm agent --id 0-3 --ids 0-3 --run lab --hub tcp/127.0.0.1:7447 --driver ros2 --driver-option config=lab.toml

``--id`` is this process's robot, or robots (``0-49``, ``0,2,5-9``): several are served
by one process on one Zenoh session (``robot_agent.host``), each still its own agent on
the wire. ``--ids`` lists every robot of the run (ranges too; default with
``--trajectory``: the trajectory's robots).
``--driver sim`` (default) simulates the robots in this process, starting from ``--pose``
(one robot) or from the initial poses of ``--trajectory``;
``--driver gateway`` drives the real or emulated robot through the link process of its
port (``swarm link``, or with ``--link`` run in this process for its hosted robots), with limits (drive, turn, workspace) and calibration from the
gateway config (docs/gateway.md); ``--driver ros2`` drives a robot speaking ROS 2 (``cmd_vel``, ``odom``,
``neighbors`` in its namespace; ``--driver-option config=FILE`` and settings, docs/ros2.md);
``--driver package.module:Class`` (or ``file.py:Class``, or an
``inchworm_swarm.drivers`` entry point) builds a lab's own driver with ``--driver-option KEY=VALUE``
and times its calls with ``--command-timeout`` (docs/drivers.md). Exit status 3 when a robot was lost.

Connects as a Zenoh client to the hub, serves commands and observation requests until
SIGTERM/SIGINT (see ``robot_agent.agent``), then closes its session and exits 0.
``python -m swarm_cli.agent ...`` is the same command with a lighter start; the library starts the same process from
its spec (``inchworm.specs.AgentHostSpec``, ``inchworm.spawn``).
"""

from __future__ import annotations

import argparse
import math

from inchworm.specs import AgentHostSpec, PortProcessSpec
from robot_agent.agent import READY_TIMEOUT_S
from robot_agent.assembly import PLUGIN_COMMAND_TIMEOUT_S, parse_ids
from runtime.errors import SwarmInputError
from runtime.wire.messages import CommandLimits
from swarm_cli.entry import leave, run_standalone
from swarm_cli.options import add_connection_options, add_model_options, add_world_options, connection_of, model_config, parse_list, positive
from swarm_cli.schema import add_fields, options_of


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("agent", help="run the agent process of one robot, or of many (--id 0-49), in a distributed run")
    add_arguments(p)
    p.set_defaults(run=run)


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The flags of the spec's fields (``AgentHostSpec``), and apart those it holds converted: the robots (``--id``,
    ``--ids``), the pose, the agent's limits in their units and defaults, ``--link`` (a ``PortProcessSpec``)."""
    p.add_argument("--id", required=True, help="this process's robot id, or ids and ranges for one process hosting many (e.g. 0-49)")
    p.add_argument("--ids", help="every robot id of the run, comma-separated, ranges allowed (e.g. 0,1,2 or 0-499); "
                                 "default with --trajectory: its robots")
    add_fields(p, AgentHostSpec, only=("trajectory",))
    add_fields(p, AgentHostSpec, only=("run_id",))
    add_connection_options(p)
    add_fields(p, AgentHostSpec, only=("seed", "driver", "driver_options"))
    p.add_argument("--command-timeout", type=positive, default=None, metavar="S",
                   help=f"a lab's own driver must finish each command and observation within this many seconds, else the robot "
                        f"is stopped and reported lost (default {PLUGIN_COMMAND_TIMEOUT_S:g}; not applied to sim and gateway unless given)")
    add_fields(p, AgentHostSpec, only=("gateway_config",))
    p.add_argument("--link", action="store_true", help="also run the link of the hosted robots' port in this process, instead of "
                                                         "`swarm link` (host every robot of the port: --id; docs/gateway.md)")
    p.add_argument("--ready-timeout", type=float, default=READY_TIMEOUT_S,
                   help=f"seconds to wait for the robot's link process before declaring this agent alive (default {READY_TIMEOUT_S:g})")
    p.add_argument("--pose", help="initial true pose x,y,heading (m, m, rad) of one simulated robot (or give --trajectory)")
    add_fields(p, AgentHostSpec, only=("motion_time",))
    p.add_argument("--max-drive", type=float, default=CommandLimits().max_drive_m, help="refuse drives longer than this (m, default 1)")
    p.add_argument("--max-turn-deg", type=float, default=math.degrees(CommandLimits().max_turn_rad),
                   help="refuse turns larger than this (default 180)")
    add_model_options(p)
    add_world_options(p, speed=True)


def initial_pose(args: argparse.Namespace) -> list[float] | None:
    """``--pose`` as x, y, heading, or None."""
    if args.pose is None:
        return None
    pose = parse_list(args.pose, "--pose", float, minimum=-math.inf)
    if len(pose) != 3:
        raise SwarmInputError(f"--pose must be x,y,heading, got {args.pose!r}")
    return pose


def spec_of(args: argparse.Namespace) -> AgentHostSpec:
    """The agent host (``--link``: port process) spec of the options."""
    pose = initial_pose(args)
    return options_of(
        args, PortProcessSpec if args.link else AgentHostSpec, **connection_of(args), robots=tuple(parse_ids(args.id, "--id")),
        run_robots=None if args.ids is None else tuple(parse_ids(args.ids, "--ids")), pose=None if pose is None else (pose[0], pose[1], pose[2]),
        model=model_config(args), command_timeout=args.command_timeout, max_drive_m=args.max_drive, max_turn_rad=math.radians(args.max_turn_deg),
        ready_timeout=args.ready_timeout, world=args.world, physics_params=tuple(args.physics_param), physics_speed=args.physics_speed)


def run(args: argparse.Namespace) -> int:
    from inchworm.process_mains import run_agent_host  # noqa: PLC0415 - zenoh when it runs

    return run_agent_host(spec_of(args))


def main(argv: list[str] | None = None) -> int:
    return run_standalone("swarm agent", add_arguments, run, argv)


if __name__ == "__main__":
    leave(main())  # no interpreter finalization under Zenoh threads (entry.leave)
