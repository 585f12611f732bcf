"""``swarm ros2``: simulated ROS 2 robots, and a run live in ROS 2 (extra ``ros2``; docs/ros2.md).

    swarm ros2 robots --trajectory traj.json [--seed 0] [model flags] [--world kinematic|physics] [--physics-param NAME=VALUE]
                      [--run RUN [--hub ENDPOINT]] [--driver-option config=FILE]
    swarm ros2 bridge --run RUN [--hub ENDPOINT] [--trajectory traj.json] [--wait S]

``robots`` starts one simulated robot per robot of the trajectory at its initial pose, each speaking the
``--driver ros2`` interface in its namespace (``cmd_vel``, ``odom``, ``neighbors``, ``ground_truth``;
``robot_agent.ros2_robots``) on a world (``--world``: ``runtime.models.world``), until Ctrl-C / SIGTERM.
In the physical world with ``--run`` its contacts, stalls and still poses go to the run's record
(``robot_agent.ros2_physics``).
Fault options (``--no-odom``, ``--silent``, ``--sightings-twice``, ``--late-sightings``) rehearse the
driver's rough cases.

``bridge`` publishes the run's estimates, poses and markers and serves ``/swarm/estop``
(``inchworm.ros2_bridge``) until the run ends or Ctrl-C; without ``--hub`` it finds the run on this host by
its run file, waiting up to ``--wait`` seconds for it to start (no live run: one line, exit 1).
Without ROS 2 installed both say which extra to install (exit 2). ROS 2's own variables choose the domain,
discovery range and middleware (``ROS_DOMAIN_ID``, ``ROS_AUTOMATIC_DISCOVERY_RANGE``, ``RMW_IMPLEMENTATION``).
"""

from __future__ import annotations

import argparse

from inchworm.specs import Ros2BridgeSpec, Ros2RobotsSpec
from runtime.errors import SwarmInputError
from swarm_cli.entry import OneLineParser, guarded, leave, limit_blas_threads
from swarm_cli.options import add_connection_options, add_model_options, connection_of, model_config, positive
from swarm_cli.schema import add_fields, options_of


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("ros2", help="simulated ROS 2 robots (robots), a run live in ROS 2 (bridge); extra ros2",
                       description="Simulated ROS 2 robots, and a run live in ROS 2 (docs/ros2.md).")
    add_arguments(p)


def add_arguments(p: argparse.ArgumentParser) -> None:
    what = p.add_subparsers(dest="ros2_command", required=True, metavar="{robots,bridge}")
    r = what.add_parser("robots", help="simulated robots of a trajectory speaking the ROS 2 driver's topics, until Ctrl-C")
    add_fields(r, Ros2RobotsSpec, exclude=("sightings_twice", "late_sightings"), types={"rate": positive, "sensing_rate": positive})
    r.add_argument("--no-odom", default="", metavar="IDS", help="robots that publish no odometry (e.g. 1,3)")
    r.add_argument("--silent", action="append", default=[], metavar="ID@N",
                   help="fault: robot ID stops publishing (and moving) when its N-th motion starts; repeatable")
    add_fields(r, Ros2RobotsSpec, only=("sightings_twice", "late_sightings"))
    add_model_options(r)
    r.set_defaults(run=run_robots)
    b = what.add_parser("bridge", help="publish a run's estimates and markers in ROS 2 and serve /swarm/estop")
    add_fields(b, Ros2BridgeSpec)
    add_connection_options(b, required=False)
    b.set_defaults(run=run_bridge)


def _silent(specs: list[str]) -> dict[int, int]:
    out = {}
    for spec in specs:
        robot, sep, n = spec.partition("@")
        if not (sep and robot.isdigit() and n.isdigit() and int(n) >= 1):
            raise SwarmInputError(f"--silent {spec}: expected ID@N with N >= 1 (e.g. 2@3)")
        out[int(robot)] = int(n)
    return out


def run_robots(args: argparse.Namespace) -> int:
    from inchworm.process_mains import run_ros2_robots  # noqa: PLC0415 - numpy and ROS 2 only when a command runs

    return run_ros2_robots(robots_spec(args))


def robots_spec(args: argparse.Namespace) -> Ros2RobotsSpec:
    """The spec of ``swarm ros2 robots``'s flags."""
    from robot_agent.assembly import parse_ids  # noqa: PLC0415

    return options_of(args, Ros2RobotsSpec, model=model_config(args), silent=_silent(args.silent),
                      no_odom=tuple(parse_ids(args.no_odom, "--no-odom")) if args.no_odom else ())


def run_bridge(args: argparse.Namespace) -> int:
    from inchworm.process_mains import run_ros2_bridge  # noqa: PLC0415 - ROS 2 and zenoh only when bridging

    return run_ros2_bridge(bridge_spec(args))


def bridge_spec(args: argparse.Namespace) -> Ros2BridgeSpec:
    """The spec of ``swarm ros2 bridge``'s flags."""
    return options_of(args, Ros2BridgeSpec, **connection_of(args))


def main(argv: list[str] | None = None) -> int:
    """``python -m swarm_cli.ros2 robots|bridge ...``: the command as a child of a launcher."""
    from inchworm.lifeline import hold_lifeline  # noqa: PLC0415

    hold_lifeline()
    limit_blas_threads()
    parser = OneLineParser(prog="swarm ros2")
    add_arguments(parser)
    args = parser.parse_args(argv)
    return guarded(f"swarm ros2 {args.ros2_command}", lambda: args.run(args))


if __name__ == "__main__":
    leave(main())
