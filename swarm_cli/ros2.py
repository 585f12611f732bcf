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
import contextlib
import logging
import os
import sys
import threading
import time
from pathlib import Path

from runtime.errors import SwarmInputError
from swarm_cli.entry import OneLineParser, guarded, leave, limit_blas_threads, on_stop_signals
from swarm_cli.options import add_connection_options, add_model_options, model_config, positive

EXIT_NO_RUN = 1


def register(sub: argparse._SubParsersAction) -> None:
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
    from robot_agent.assembly import driver_options, parse_ids  # noqa: PLC0415 - numpy and ROS 2 only when a command runs
    from robot_agent.ros2_config import Ros2Config  # noqa: PLC0415
    from robot_agent.ros2_robots import SimRobots  # noqa: PLC0415
    from runtime.models.trajectory import Trajectory  # noqa: PLC0415
    from runtime.models.world import make_world  # noqa: PLC0415
    from runtime.wire.ros2 import require_ros2  # noqa: PLC0415

    require_ros2("swarm ros2 robots")
    traj = Trajectory.load(args.trajectory)
    no_odom = frozenset(parse_ids(args.no_odom, "--no-odom")) if args.no_odom else frozenset()
    silent = _silent(args.silent)
    unknown = sorted((set(no_odom) | set(silent)) - {int(i) for i in traj.ids})
    if unknown:
        raise SwarmInputError(f"robots {unknown} of --no-odom/--silent are not robots of {args.trajectory}")
    if args.late_sightings < 0:
        raise SwarmInputError(f"--late-sightings must be >= 0, got {args.late_sightings:g}")
    cfg = Ros2Config.load(driver_options(args.driver_option))
    if args.world != "physics" and (args.physics_param or args.run_id or args.hub):
        raise SwarmInputError("--physics-param, --run and --hub are for the physical world: they need --world physics")
    if args.hub and not args.run_id:
        raise SwarmInputError("--hub names the Zenoh endpoint of a run: it needs --run RUN")
    if args.world == "physics":
        world, note = _physics_world(args, traj, cfg)
    else:
        world, note = make_world(args.world, traj.ids, traj.initial_poses, model_config(args), args.seed), ""
    with contextlib.ExitStack() as stack:
        recorder = _recorder(args, world, stack) if args.run_id else None
        truth = "" if args.no_ground_truth else cfg.ground_truth or "ground_truth"
        robots = SimRobots(world, cfg, rate_hz=args.rate, sensing_hz=args.sensing_rate, ground_truth=truth, no_odom=no_odom,
                           silent=silent, twice=args.sightings_twice, late_s=args.late_sightings,
                           after_step=recorder.poll if recorder else None)
        on_stop_signals(robots.stop)
        domain = os.environ.get("ROS_DOMAIN_ID", "0")
        print(f"swarm ros2 robots: {len(traj.ids)} robots in {cfg.namespace_of(int(traj.ids[0]))} ... "
              f"{cfg.namespace_of(int(traj.ids[-1]))} (ROS_DOMAIN_ID {domain}), world {args.world}{note}"
              + (f"; drive them with --driver ros2 --driver-option ground_truth={truth} for P_f" if truth else ""), file=sys.stderr, flush=True)
        try:
            robots.run()
        finally:
            robots.close()
        if recorder is not None:
            print(f"swarm ros2 robots: {recorder.published} physics events published to run {args.run_id}", file=sys.stderr, flush=True)
    return 0


def _physics_world(args: argparse.Namespace, traj, cfg):
    """The physical world of ``--physics-param`` (pymunk 7 needed), and a note when the driver's default speeds
    exceed its wheels' (the driver would count on speeds the wheels cannot reach)."""
    from runtime.world.params import parse_physics_params  # noqa: PLC0415 - the physics extra, only when asked for
    from runtime.world.physics import require_pymunk  # noqa: PLC0415
    from runtime.world.velocity import PhysicsWorld  # noqa: PLC0415

    require_pymunk()
    params = parse_physics_params(list(args.physics_param), model_config(args))
    world = PhysicsWorld(traj.ids, traj.initial_poses, params, args.seed)
    half = params.track_m / 2.0
    over = (max(cfg.max_linear_speed, cfg.max_angular_speed * half) > params.max_wheel_speed_m_s
            or max(cfg.linear_accel, cfg.angular_accel * half) > params.max_wheel_accel_m_s2)
    note = (f" (wheels at most {params.max_wheel_speed_m_s:g} m/s, {params.max_wheel_accel_m_s2:g} m/s^2: give the driver "
            f"limits within them, docs/ros2.md)") if over else ""
    return world, note


def _recorder(args: argparse.Namespace, world, stack: contextlib.ExitStack):
    """The ``PhysicsRecorder`` of ``--run`` on a session of its own (``--hub``, else the run file of a live run)."""
    from robot_agent.ros2_physics import PhysicsRecorder  # noqa: PLC0415
    from runtime.wire.keys import validate_run  # noqa: PLC0415
    from runtime.wire.run_file import read_run  # noqa: PLC0415
    from runtime.wire.transport import ZenohSettings, open_session  # noqa: PLC0415

    validate_run(args.run_id)
    hub = args.hub
    if not hub:
        entry = read_run(args.run_id)
        if entry is None:
            raise SwarmInputError(f"--run {args.run_id}: no live run of that id on this host (give --hub ENDPOINT)")
        hub = entry["hub"]
    session = stack.enter_context(open_session(ZenohSettings("client", connect=(hub,))))
    recorder = PhysicsRecorder(session, args.run_id, world)
    stack.callback(recorder.close)
    return recorder


def _hub_settings(args: argparse.Namespace):
    """The run's Zenoh settings: ``--hub`` / ``--zenoh-config``, else its run file, waited for up to ``--wait`` s; None: no run."""
    from runtime.wire.run_file import read_run  # noqa: PLC0415
    from runtime.wire.transport import ZenohSettings  # noqa: PLC0415

    if args.hub or args.zenoh_config:
        return ZenohSettings("client", connect=(args.hub,) if args.hub else (), config_file=args.zenoh_config)
    deadline = time.monotonic() + max(args.wait, 0.0)
    while (entry := read_run(args.run_id)) is None:
        if time.monotonic() >= deadline:
            return None
        time.sleep(0.1)
    args.hub = entry["hub"]
    return ZenohSettings("client", connect=(args.hub,))


def run_bridge(args: argparse.Namespace) -> int:
    from inchworm.ros2_bridge import Bridge  # noqa: PLC0415 - ROS 2 and zenoh only when bridging
    from runtime.models.config import ModelConfig  # noqa: PLC0415
    from runtime.models.trajectory import Trajectory  # noqa: PLC0415
    from runtime.wire.keys import validate_run  # noqa: PLC0415
    from runtime.wire.ros2 import require_ros2  # noqa: PLC0415
    from runtime.wire.transport import open_session  # noqa: PLC0415

    require_ros2("swarm ros2 bridge")
    validate_run(args.run_id)
    traj = Trajectory.load(args.trajectory) if args.trajectory else None
    settings = _hub_settings(args)
    if settings is None:
        waited = f" within {args.wait:g} s" if args.wait > 0 else ""
        print(f"swarm ros2 bridge: no live run {args.run_id!r} on this host{waited} (give --hub ENDPOINT, or --wait S to wait for it)",
              file=sys.stderr, flush=True)
        return EXIT_NO_RUN
    stop = threading.Event()
    on_stop_signals(stop.set)
    radius = ModelConfig().robot_radius_m if args.robot_radius is None else args.robot_radius
    with open_session(settings) as session:
        bridge = Bridge(session, settings, args.run_id, traj, radius)
        print(f"swarm ros2 bridge: run {args.run_id} on {args.hub or args.zenoh_config} -> /swarm/estimates, /swarm/robot<id>/pose, "
              f"/swarm/markers, service /swarm/estop (ROS_DOMAIN_ID {os.environ.get('ROS_DOMAIN_ID', '0')})", file=sys.stderr, flush=True)
        try:
            bridge.wait(stop)
        finally:
            bridge.close()
    print(f"swarm ros2 bridge: run {args.run_id} over, {bridge.published} estimates published", file=sys.stderr, flush=True)
    return 0


def main(argv: list[str] | None = None) -> int:
    """``python -m swarm_cli.ros2 robots|bridge ...``: the command as a child of a launcher."""
    from inchworm.lifeline import hold_lifeline  # noqa: PLC0415

    hold_lifeline()
    limit_blas_threads()
    logging.basicConfig(level=logging.WARNING, format="swarm ros2: %(levelname)s %(message)s", stream=sys.stderr)
    parser = OneLineParser(prog="swarm ros2")
    add_arguments(parser)
    args = parser.parse_args(argv)
    return guarded(f"swarm ros2 {args.ros2_command}", lambda: args.run(args))


if __name__ == "__main__":
    leave(main())
