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
from pathlib import Path

from inchworm.specs import Ros2BridgeSpec, Ros2RobotsSpec
from runtime.errors import SwarmInputError
from swarm_cli.entry import OneLineParser, guarded, leave, limit_blas_threads
from swarm_cli.options import add_connection_options, add_model_options, model_config, positive


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("ros2", help="simulated ROS 2 robots (robots), a run live in ROS 2 (bridge); extra ros2",
                       description="Simulated ROS 2 robots, and a run live in ROS 2 (docs/ros2.md).")
    add_arguments(p)


def add_arguments(p: argparse.ArgumentParser) -> None:
    what = p.add_subparsers(dest="ros2_command", required=True, metavar="{robots,bridge}")
    r = what.add_parser("robots", help="simulated robots of a trajectory speaking the ROS 2 driver's topics, until Ctrl-C")
    r.add_argument("--trajectory", type=Path, required=True, help="trajectory JSON: the robots and their initial poses")
    r.add_argument("--seed", type=int, default=0, help="seed of the motion and sensing noise (default 0)")
    r.add_argument("--world", default="kinematic",
                   help="the world the robots move in: kinematic (the project's noise model, the default) or physics (a rigid-body "
                        "world: wheels within their limits that slip, bodies that push; pip install 'inchworm-swarm[physics]')")
    r.add_argument("--physics-param", action="append", default=[], metavar="NAME=VALUE",
                   help="with --world physics: a parameter of the physical world (docs/physics.md), repeatable")
    r.add_argument("--run", dest="run_id", default=None,
                   help="with --world physics: the run whose record gets the world's contacts, stalls and poses (PhysicsEvent)")
    r.add_argument("--hub", default=None, help="with --run: the run's Zenoh endpoint (default: the run file of a run on this host)")
    r.add_argument("--driver-option", action="append", default=[], metavar="KEY=VALUE",
                   help="the ROS 2 driver's settings the robots share with it: config=FILE, namespace, frame, topic names "
                        "(docs/ros2.md); repeatable")
    r.add_argument("--rate", type=positive, default=50.0, help="world steps and odometry per second (default 50)")
    r.add_argument("--sensing-rate", type=positive, default=10.0, help="sensor frames per second on neighbors (default 10)")
    r.add_argument("--no-ground-truth", action="store_true",
                   help="publish no true pose (default: on the settings' ground_truth topic, else ground_truth)")
    r.add_argument("--no-odom", default="", metavar="IDS", help="robots that publish no odometry (e.g. 1,3)")
    r.add_argument("--silent", action="append", default=[], metavar="ID@N",
                   help="fault: robot ID stops publishing (and moving) when its N-th motion starts; repeatable")
    r.add_argument("--sightings-twice", action="store_true", help="fault: every sighting is published twice")
    r.add_argument("--late-sightings", type=float, default=0.0, metavar="S",
                   help="fault: every sighting is published again S seconds later with its original stamp")
    add_model_options(r)
    r.set_defaults(run=run_robots)
    b = what.add_parser("bridge", help="publish a run's estimates and markers in ROS 2 and serve /swarm/estop")
    b.add_argument("--run", dest="run_id", required=True, help="run id")
    b.add_argument("--trajectory", type=Path, default=None, help="the run's trajectory JSON, for the desired configuration markers")
    b.add_argument("--robot-radius", type=float, default=None, help="body radius of the markers in m (default the model's)")
    b.add_argument("--wait", type=float, default=0.0, metavar="S", help="wait up to S seconds for the run to start (default 0)")
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
    from robot_agent.assembly import parse_ids  # noqa: PLC0415

    return run_ros2_robots(Ros2RobotsSpec(
        trajectory=str(args.trajectory), seed=args.seed, model=model_config(args), world=args.world, physics_params=tuple(args.physics_param),
        run_id=args.run_id, hub=args.hub, driver_options=tuple(args.driver_option), rate=args.rate, sensing_rate=args.sensing_rate,
        no_ground_truth=args.no_ground_truth, no_odom=tuple(parse_ids(args.no_odom, "--no-odom")) if args.no_odom else (),
        silent=_silent(args.silent), sightings_twice=args.sightings_twice, late_sightings=args.late_sightings))


def run_bridge(args: argparse.Namespace) -> int:
    from inchworm.process_mains import run_ros2_bridge  # noqa: PLC0415 - ROS 2 and zenoh only when bridging

    return run_ros2_bridge(Ros2BridgeSpec(run_id=args.run_id, trajectory=None if args.trajectory is None else str(args.trajectory),
                                          robot_radius=args.robot_radius, wait=args.wait, hub=args.hub, zenoh_config=args.zenoh_config))


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
