"""The main function of every process kind, from its spec (``inchworm.specs``): what ``swarm agent``, ``swarm link``,
``swarm coordinator``, ``swarm emulate-robots``, ``swarm ros2 robots|bridge``, ``swarm router``, ``swarm record`` and
``swarm launch`` run once their flags are a spec, and what ``python -m inchworm.spawn`` runs for a spec it reads. Each
returns the command's exit status; bad input raises ``SwarmInputError`` naming the option, a connection that cannot be made ``SwarmConnectionError``
(``inchworm.entry.guarded`` prints it and gives the exit code of its class, ``EXIT_CODES``).
Heavy modules (zenoh, scipy, ROS 2) are imported by the function that needs them.
"""

from __future__ import annotations

import logging
import math
import os
import sys
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, cast

from inchworm.entry import EXIT_OUTPUT, EXIT_RUN, exit_code, on_stop_signals
from inchworm.output import print_json
from inchworm.specs import (
    FLAGS,
    AgentHostSpec,
    CoordinatorSpec,
    EmulatorSpec,
    LaunchSpec,
    LinkSpec,
    PortProcessSpec,
    RecorderSpec,
    Ros2BridgeSpec,
    Ros2RobotsSpec,
    RouterSpec,
    selection_spec,
)
from runtime.errors import OptionError, SwarmConnectionError
from runtime.models.config import ModelConfig

if TYPE_CHECKING:
    import contextlib

    from inchworm.launcher import LaunchOptions
    from robot_agent.emulator import PortEmulator
    from robot_agent.ros2_config import Ros2Config
    from robot_agent.ros2_physics import PhysicsRecorder
    from runtime.models.trajectory import Trajectory
    from runtime.models.world import World
    from runtime.recording.mcap_log import McapRecorder
    from runtime.wire.transport import ZenohSettings
    from runtime.world.params import PhysicsParams
    from runtime.world.velocity import PhysicsWorld

EXIT_NO_RUN = 1  # swarm ros2 bridge: no live run
SAFE_OPEN_FILES = 65536  # a flood must not exhaust the router's files: one source address alone holds ~28,000 connections


def connection(hub: str | None, zenoh_config: str | None, run_id: str | None, *, required: bool = True) -> tuple[ZenohSettings | None, str]:
    """The client ``ZenohSettings`` of a hub and/or a Zenoh config file, and how to name it; without either, the hub of
    the live run ``run_id`` (its run file) if ``required``, else None."""
    from runtime.wire.transport import ZenohSettings  # noqa: PLC0415 - zenoh, only when a process runs

    if hub is None and zenoh_config is None:
        if not required:
            return None, ""
        if run_id is None:
            raise OptionError("hub", "ENDPOINT (e.g. tcp/127.0.0.1:7447) or `zenoh_config` FILE must be given", FLAGS)
        from runtime.wire.run_file import hub_of  # noqa: PLC0415

        hub = hub_of(run_id)
    return ZenohSettings("client", connect=(hub,) if hub else (), config_file=zenoh_config), hub or f"config {zenoh_config}"


def physical_world(on: bool, params: tuple[str, ...], model: ModelConfig, switch: str) -> PhysicsParams | None:
    """The ``PhysicsParams`` of ``params`` when the physical world is ``on`` (the option ``switch`` turns it on, as
    "`physics`" or "`world` physics", a backquoted option name), else None."""
    if not on:
        if params:
            raise OptionError("physics_params", f"sets the physical world: it needs {switch}", FLAGS)
        return None
    from runtime.world.params import parse_physics_params  # noqa: PLC0415 - the physics extra, only when asked for
    from runtime.world.physics import require_pymunk  # noqa: PLC0415

    require_pymunk()
    return parse_physics_params(list(params), model)


def run_agent_host(spec: AgentHostSpec) -> int:
    """``swarm agent``: the agents of ``spec.robots`` until SIGTERM/SIGINT (with a ``PortProcessSpec`` also its port's link)."""
    from robot_agent.agent import READY_TIMEOUT_S  # noqa: PLC0415 - zenoh when it runs
    from robot_agent.assembly import AgentSpec, build_agents, build_links, driver_options, format_ids  # noqa: PLC0415
    from robot_agent.host import AgentHost  # noqa: PLC0415
    from runtime.models.trajectory import Trajectory  # noqa: PLC0415
    from runtime.wire.keys import validate_run  # noqa: PLC0415
    from runtime.wire.messages import CommandLimits  # noqa: PLC0415

    settings, _ = connection(spec.hub, spec.zenoh_config, spec.run_id)
    assert settings is not None, "required"
    validate_run(spec.run_id)
    default = CommandLimits()
    limits = CommandLimits(max_drive_m=default.max_drive_m if spec.max_drive_m is None else spec.max_drive_m,
                           max_turn_rad=default.max_turn_rad if spec.max_turn_rad is None else spec.max_turn_rad)
    run_robots = None if spec.run_robots is None else list(spec.run_robots)
    trajectory = None if spec.trajectory is None else Path(spec.trajectory)
    agent_spec = AgentSpec(settings, spec.run_id, list(spec.robots), run_robots, None if run_robots is None else format_ids(run_robots),
                           None if trajectory is None else Trajectory.load(trajectory), trajectory,
                           None if spec.pose is None else list(spec.pose), spec.driver, driver_options(list(spec.driver_options)),
                           None if spec.gateway_config is None else Path(spec.gateway_config), spec.seed, spec.model, spec.motion_time,
                           limits, READY_TIMEOUT_S if spec.ready_timeout is None else spec.ready_timeout, spec.command_timeout,
                           isinstance(spec, PortProcessSpec),
                           physical_world(spec.world == "physics", spec.physics_params, spec.model, "`world` physics"), spec.physics_speed)
    agents = build_agents(agent_spec)
    links = build_links(agent_spec, agents[0].ids)
    logging.basicConfig(level=logging.WARNING, format=f"agent {format_ids(spec.robots)}: %(levelname)s %(message)s", stream=sys.stderr)
    server = agents[0] if len(agents) == 1 and not links else AgentHost(agents[0].settings, agents, links)
    on_stop_signals(server.stop)
    status = server.run()
    for line in getattr(server, "link_summaries", ()):
        print(f"swarm link: {line}", file=sys.stderr, flush=True)
    return status


def run_link(spec: LinkSpec) -> int:
    """``swarm link``: the link of one port until SIGTERM/SIGINT."""
    import contextlib  # noqa: PLC0415

    from robot_agent.link import Link  # noqa: PLC0415 - zenoh and pyserial when it runs
    from runtime.gateway.config import GatewayConfig  # noqa: PLC0415
    from runtime.wire.keys import validate_run  # noqa: PLC0415
    from runtime.wire.transport import claim_identities, open_session  # noqa: PLC0415

    logging.basicConfig(level=logging.WARNING, format=f"link {spec.port}: %(levelname)s %(message)s", stream=sys.stderr)
    config = GatewayConfig.load(Path(spec.config))
    port = config.port(spec.port)
    validate_run(spec.run_id)
    settings, _ = connection(spec.hub, spec.zenoh_config, spec.run_id)
    assert settings is not None, "required"
    with open_session(settings) as session:
        claim_identities(session, spec.run_id, ports=[port.name])  # before the device is opened: one link per port
        with contextlib.closing(Link.open(session, spec.run_id, port, config)) as link:
            on_stop_signals(link.stop)
            print(f"swarm link: port {port.name} on {port.device} ({port.transport}), robots "
                  f"{','.join(map(str, port.robots))}, run {spec.run_id}", file=sys.stderr, flush=True)
            status = link.run()
            print(f"swarm link: {link.summary()}", file=sys.stderr, flush=True)
            return status


def run_coordinator(spec: CoordinatorSpec) -> int:
    """``swarm coordinator``: the run (or ``standby`` / ``resume``), its summary, plots, result and ``json`` line."""
    logging.basicConfig(level=logging.WARNING, format="coordinator: %(levelname)s %(message)s", stream=sys.stderr)
    from coordinator.node.stop import StopSignals  # noqa: PLC0415 - scipy and zenoh when it runs

    signals = StopSignals()  # SIGINT/SIGTERM end the run; never an exception inside the recording's finish
    from coordinator.node.process import CoordinatorOptions, default_recording, recording_line, run_coordinator as run_it, say  # noqa: PLC0415
    from inchworm.simulation import run_json, summary_text, write_run_outputs  # noqa: PLC0415
    from runtime.models.trajectory import Trajectory  # noqa: PLC0415

    settings, label = connection(spec.hub, spec.zenoh_config, spec.run_id)
    assert settings is not None, "required"
    selection = spec.selection.config()
    record = None if spec.no_record else Path(spec.record) if spec.record else default_recording(
        spec.run_id, "standby" if spec.standby else "resume" if spec.resume else "")
    options = CoordinatorOptions(
        Trajectory.load(Path(spec.trajectory)), spec.run_id, settings, label, spec.method, spec.seed, spec.localizer, spec.model,
        None if spec.model_file is None else Path(spec.model_file), selection, spec.start_timeout, spec.step_timeout, spec.on_lost,
        spec.min_robots, truth=spec.truth, record=record, foxglove_port=spec.foxglove, command=spec.command,
        on_record_error=spec.on_record_error, standby=spec.standby, resume=None if spec.resume is None else Path(spec.resume),
        rejoin=spec.rejoin)
    outcome = run_it(options, signals, lambda done, total, step: say(f"config {done}/{total} done (step {step})"))
    status = 0
    if outcome.error is not None:  # another coordinator holds the run (4), lost or stopped (3), the recording stopped it (5)
        print(f"swarm coordinator: error: {outcome.error}", file=sys.stderr, flush=True)
        status = exit_code(outcome.error) or EXIT_RUN
        if outcome.result is None:  # nothing ran (the agents did not come up, another coordinator holds the run)
            return status
    if outcome.result is None:  # a standby whose run finished without it
        return EXIT_OUTPUT if outcome.recording_error is not None else 0
    result = outcome.result
    plots, errors = write_run_outputs(result, None if spec.result is None else Path(spec.result), None if spec.out is None else Path(spec.out))
    for line in errors:
        print(f"swarm coordinator: error: {line}", file=sys.stderr, flush=True)
    failed = outcome.recording_error is not None or bool(errors)
    radius = options.model.robot_radius_m
    print(summary_text(result, spec.method, spec.localizer, radius))
    if plots:
        print(f"wrote {', '.join(plots)}")
    if outcome.recording:
        print(recording_line(outcome.recording))
    elif outcome.recording_error is not None:
        print(f"recording failed: {outcome.recording_error}")
    if spec.json:
        print_json(run_json(result, spec.method, spec.localizer, spec.seed, plots, outcome.recording["path"] if outcome.recording else None,
                            radius, None if outcome.error is None else str(outcome.error)))
    outcome.live.linger(spec.linger)
    return EXIT_OUTPUT if failed and status == 0 else status


def run_emulator(spec: EmulatorSpec) -> int:
    """``swarm emulate-robots``: the robots of a gateway config on ptys until SIGTERM/SIGINT."""
    from robot_agent.emulator import FaultPlan  # noqa: PLC0415
    from robot_agent.emulator_process import check_radio_faults, serve_emulators  # noqa: PLC0415
    from runtime.gateway.config import GatewayConfig  # noqa: PLC0415
    from runtime.models.trajectory import Trajectory  # noqa: PLC0415

    check_radio_faults(spec.drop, spec.corrupt, spec.delay)
    if spec.blackout is not None and (spec.blackout[0] < 1 or not (math.isfinite(spec.blackout[1]) and spec.blackout[1] > 0)):
        raise OptionError("blackout", f"must be STEP:SECONDS with a step >= 1 and seconds > 0 (e.g. 2:1.0), "
                                      f"got {spec.blackout[0]}:{spec.blackout[1]:g}", FLAGS)
    faults = FaultPlan(drop_prob=spec.drop, corrupt_prob=spec.corrupt, delay_s=spec.delay, drop_rx=frozenset(spec.drop_rx),
                       drop_tx=frozenset(spec.drop_tx), blackout=spec.blackout, seed=spec.seed)

    def ready(ports: list[PortEmulator], devices: dict[str, str]) -> None:
        for pe in ports:
            print(f"port {pe.port_name}: {pe.device} (robots {','.join(map(str, pe.robots))})", flush=True)
        if spec.json:
            print_json({"ports": devices, "config": spec.write_config})

    physics = physical_world(spec.physics, spec.physics_params, spec.model, "`physics`")
    settings, _ = connection(spec.hub, spec.zenoh_config, spec.run_id, required=False)
    config = Path(spec.config)
    serve_emulators(GatewayConfig.load(config), config, Trajectory.load(Path(spec.trajectory)), Path(spec.trajectory), spec.model,
                    spec.seed, faults, settings=settings, run_id=spec.run_id, miscalibrate=spec.miscalibrate,
                    motion_time_s=spec.motion_time, events=None if spec.events is None else Path(spec.events),
                    write_config=None if spec.write_config is None else Path(spec.write_config), on_ready=ready,
                    say=lambda text: print(f"swarm emulate-robots: {text}", file=sys.stderr, flush=True), physics=physics,
                    physics_speed=spec.physics_speed)
    return 0


def run_ros2_robots(spec: Ros2RobotsSpec) -> int:
    """``swarm ros2 robots``: simulated robots speaking the ROS 2 driver's topics until SIGTERM/SIGINT (in the physical
    world with ``run_id``: its physics events published to that run)."""
    import contextlib  # noqa: PLC0415

    from robot_agent.assembly import driver_options  # noqa: PLC0415 - numpy and ROS 2 only when it runs
    from robot_agent.ros2_config import Ros2Config  # noqa: PLC0415
    from robot_agent.ros2_robots import SimRobots  # noqa: PLC0415
    from runtime.models.trajectory import Trajectory  # noqa: PLC0415
    from runtime.models.world import make_world  # noqa: PLC0415
    from runtime.wire.ros2 import require_ros2  # noqa: PLC0415

    logging.basicConfig(level=logging.WARNING, format="swarm ros2: %(levelname)s %(message)s", stream=sys.stderr)
    require_ros2("swarm ros2 robots")
    traj = Trajectory.load(Path(spec.trajectory))
    unknown = sorted((set(spec.no_odom) | set(spec.silent)) - {int(i) for i in traj.ids})
    if unknown:
        raise OptionError("no_odom", f"/`silent`: robots {unknown} are not robots of {spec.trajectory}", FLAGS)
    if any(n < 1 for n in spec.silent.values()):
        raise OptionError("silent", f": the motion a robot falls silent at must be >= 1, got {spec.silent}", FLAGS)
    if spec.late_sightings < 0:
        raise OptionError("late_sightings", f"must be >= 0, got {spec.late_sightings:g}", FLAGS)
    cfg = Ros2Config.load(driver_options(list(spec.driver_options)))
    if spec.world != "physics" and (spec.physics_params or spec.run_id or spec.hub):
        raise OptionError("physics_params", ", `run_id` and `hub` are for the physical world: they need `world` physics", FLAGS)
    if spec.hub and not spec.run_id:
        raise OptionError("hub", "names the Zenoh endpoint of a run: it needs `run_id` RUN", FLAGS)
    world: World
    if spec.world == "physics":
        world, note = _ros2_physics_world(spec, traj, cfg)
    else:
        world, note = make_world(spec.world, traj.ids, traj.initial_poses, spec.model, spec.seed), ""
    with contextlib.ExitStack() as stack:
        # a run (``run_id``) is the physical world's only (checked above)
        recorder = _ros2_physics_recorder(spec, cast("PhysicsWorld", world), stack) if spec.run_id else None
        truth = "" if spec.no_ground_truth else cfg.ground_truth or "ground_truth"
        robots = SimRobots(world, cfg, rate_hz=spec.rate, sensing_hz=spec.sensing_rate, ground_truth=truth, no_odom=frozenset(spec.no_odom),
                           silent=dict(spec.silent), twice=spec.sightings_twice, late_s=spec.late_sightings,
                           after_step=recorder.poll if recorder else None)
        on_stop_signals(robots.stop)
        domain = os.environ.get("ROS_DOMAIN_ID", "0")
        print(f"swarm ros2 robots: {len(traj.ids)} robots in {cfg.namespace_of(int(traj.ids[0]))} ... "
              f"{cfg.namespace_of(int(traj.ids[-1]))} (ROS_DOMAIN_ID {domain}), world {spec.world}{note}"
              + (f"; drive them with --driver ros2 --driver-option ground_truth={truth} for P_f" if truth else ""), file=sys.stderr, flush=True)
        try:
            robots.run()
        finally:
            robots.close()
        if recorder is not None:
            print(f"swarm ros2 robots: {recorder.published} physics events published to run {spec.run_id}", file=sys.stderr, flush=True)
    return 0


def _ros2_physics_world(spec: Ros2RobotsSpec, traj: Trajectory, cfg: Ros2Config) -> tuple[PhysicsWorld, str]:
    """The physical world of ``physics_params`` (pymunk 7 needed), and a note when the driver's default speeds
    exceed its wheels' (the driver would count on speeds the wheels cannot reach)."""
    from runtime.world.velocity import PhysicsWorld  # noqa: PLC0415 - the physics extra, only when asked for

    params = physical_world(True, spec.physics_params, spec.model, "`world` physics")
    assert params is not None, "on"
    world = PhysicsWorld(traj.ids, traj.initial_poses, params, spec.seed)
    half = params.track_m / 2.0
    over = (max(cfg.max_linear_speed, cfg.max_angular_speed * half) > params.max_wheel_speed_m_s
            or max(cfg.linear_accel, cfg.angular_accel * half) > params.max_wheel_accel_m_s2)
    note = (f" (wheels at most {params.max_wheel_speed_m_s:g} m/s, {params.max_wheel_accel_m_s2:g} m/s^2: give the driver "
            f"limits within them, docs/ros2.md)") if over else ""
    return world, note


def _ros2_physics_recorder(spec: Ros2RobotsSpec, world: PhysicsWorld, stack: contextlib.ExitStack) -> PhysicsRecorder:
    """The ``PhysicsRecorder`` of ``run_id`` on a session of its own (``hub``, else the run file of a live run)."""
    from robot_agent.ros2_physics import PhysicsRecorder  # noqa: PLC0415
    from runtime.wire.keys import validate_run  # noqa: PLC0415
    from runtime.wire.run_file import read_run  # noqa: PLC0415
    from runtime.wire.transport import ZenohSettings, open_session  # noqa: PLC0415

    assert spec.run_id is not None, "a recorder needs the run"
    validate_run(spec.run_id)
    hub = spec.hub
    if not hub:
        entry = read_run(spec.run_id)
        if entry is None:
            raise OptionError("run_id", f"{spec.run_id}: no live run of that id on this host (give `hub` ENDPOINT)", FLAGS)
        hub = entry["hub"]
    session = stack.enter_context(open_session(ZenohSettings("client", connect=(hub,))))
    recorder = PhysicsRecorder(session, spec.run_id, world)
    stack.callback(recorder.close)
    return recorder


def run_ros2_bridge(spec: Ros2BridgeSpec) -> int:
    """``swarm ros2 bridge``: the run's estimates and markers in ROS 2 and ``/swarm/estop`` until the run ends (no live run: 1)."""
    from inchworm.ros2_bridge import Bridge  # noqa: PLC0415 - ROS 2 and zenoh only when bridging
    from runtime.models.trajectory import Trajectory  # noqa: PLC0415
    from runtime.wire.keys import validate_run  # noqa: PLC0415
    from runtime.wire.ros2 import require_ros2  # noqa: PLC0415
    from runtime.wire.run_file import read_run  # noqa: PLC0415
    from runtime.wire.transport import open_session  # noqa: PLC0415

    logging.basicConfig(level=logging.WARNING, format="swarm ros2: %(levelname)s %(message)s", stream=sys.stderr)
    require_ros2("swarm ros2 bridge")
    validate_run(spec.run_id)
    traj = Trajectory.load(Path(spec.trajectory)) if spec.trajectory else None
    hub = spec.hub
    if hub is None and spec.zenoh_config is None:  # the run's run file, waited for up to ``wait`` s
        deadline = time.monotonic() + max(spec.wait, 0.0)
        while (entry := read_run(spec.run_id)) is None:
            if time.monotonic() >= deadline:
                waited = f" within {spec.wait:g} s" if spec.wait > 0 else ""
                print(f"swarm ros2 bridge: no live run {spec.run_id!r} on this host{waited} (give --hub ENDPOINT, or --wait S to wait for it)",
                      file=sys.stderr, flush=True)
                return EXIT_NO_RUN
            time.sleep(0.1)
        hub = entry["hub"]
    settings, label = connection(hub, spec.zenoh_config, spec.run_id)
    assert settings is not None, "given"
    stop = threading.Event()
    on_stop_signals(stop.set)
    radius = ModelConfig().robot_radius_m if spec.robot_radius is None else spec.robot_radius
    with open_session(settings) as session:
        bridge = Bridge(session, settings, spec.run_id, traj, radius)
        print(f"swarm ros2 bridge: run {spec.run_id} on {hub or spec.zenoh_config} -> /swarm/estimates, /swarm/robot<id>/pose, "
              f"/swarm/markers, service /swarm/estop (ROS_DOMAIN_ID {os.environ.get('ROS_DOMAIN_ID', '0')})", file=sys.stderr, flush=True)
        try:
            bridge.wait(stop)
        finally:
            bridge.close()
    print(f"swarm ros2 bridge: run {spec.run_id} over, {bridge.published} estimates published", file=sys.stderr, flush=True)
    return 0


def run_recorder(spec: RecorderSpec) -> int:
    """``swarm record``: record every message of the run until SIGINT/SIGTERM/SIGHUP, then print the file and its counts."""
    from runtime.recording.mcap_log import STOP_DRAIN_S, counts_text, record_run, run_metadata  # noqa: PLC0415 - zenoh, mcap when it runs
    from runtime.wire.keys import run_wildcard, validate_run  # noqa: PLC0415

    validate_run(spec.run_id)
    settings, label = connection(spec.hub, spec.zenoh_config, spec.run_id)
    assert settings is not None, "required"
    out = Path(spec.out) if spec.out is not None else Path("recordings") / f"{spec.run_id}.mcap"
    meta = run_metadata(label, spec.command, spec.seed, None if spec.trajectory is None else Path(spec.trajectory), spec.params)
    stop = threading.Event()
    on_stop_signals(stop.set)

    def ready(rec: McapRecorder) -> None:
        print(f"swarm record: recording {run_wildcard(spec.run_id)} from {label} to {rec.path}", file=sys.stderr, flush=True)

    result = record_run(settings, spec.run_id, out, meta, stop, on_ready=ready, drain_s=STOP_DRAIN_S)
    print(f"wrote {result['path']}: {counts_text(result)}" + (f" ({result['undecodable']} undecodable)" if result["undecodable"] else ""),
          flush=True)
    if spec.json:
        print_json(result)
    return 0


def run_router(spec: RouterSpec) -> int:
    """``swarm router``: a Zenoh router until SIGINT/SIGTERM/SIGHUP."""
    import resource  # noqa: PLC0415
    import signal  # noqa: PLC0415

    from runtime.wire.router import router_settings  # noqa: PLC0415 - zenoh when it runs
    from runtime.wire.transport import open_session  # noqa: PLC0415

    settings = router_settings(list(spec.listen), spec.config)
    stop = threading.Event()
    previous = {sig: signal.signal(sig, lambda *_: stop.set()) for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    try:
        try:
            session = open_session(settings)
        except ConnectionError as exc:
            raise SwarmConnectionError(f"cannot start the router on {', '.join(settings.listen)}: {exc.__cause__ or exc}") from None
        with session:
            source = f" (config {spec.config})" if spec.config else ""
            print(f"swarm router: listening on {', '.join(settings.listen)}{source}; zid {session.info.zid()}",
                  file=sys.stderr, flush=True)
            files = resource.getrlimit(resource.RLIMIT_NOFILE)[0]  # Zenoh raised the soft limit to the hard one
            if files < SAFE_OPEN_FILES:
                print(f"swarm router: warning: {files} open files allowed: a flood of that many connections blocks every listener, "
                      f"the stop path's too (raise the hard limit to {SAFE_OPEN_FILES}, e.g. LimitNOFILE= of its systemd unit; "
                      "deploy/README.md, \"The stop path\")", file=sys.stderr, flush=True)
            if spec.json:
                print_json({"zid": str(session.info.zid()), "listen": list(settings.listen), "config": spec.config})
            while not stop.wait(0.5):
                pass
    finally:
        for sig, handler in previous.items():  # matters when run in-process (tests)
            signal.signal(sig, handler)
    print("swarm router: stopped", file=sys.stderr, flush=True)
    return 0


def run_launch(spec: LaunchSpec) -> int:
    """``swarm launch`` / ``swarm demo``: the whole run (``inchworm.launcher.launch``); its JSON object printed as the last line."""
    from inchworm.launcher import launch  # noqa: PLC0415 - zenoh and scipy only when launching

    return launch(launch_options(spec), emit_json=print_json, capture=spec.json).status


def launch_options(spec: LaunchSpec) -> LaunchOptions:
    """The ``LaunchOptions`` of a launch spec, by concern (the spec's fields are theirs, flat)."""
    from inchworm.launcher import DriverOptions, FaultOptions, LaunchOptions, OutputOptions, SwarmOptions  # noqa: PLC0415


    def path(text: str | None) -> Path | None:
        return None if text is None else Path(text)

    return LaunchOptions(
        swarm=SwarmOptions(
            trajectory=path(spec.trajectory), robots=spec.robots, configs=spec.configs, trajectory_seed=spec.trajectory_seed,
            method=spec.method, seed=spec.seed, model=spec.model, model_file=path(spec.model_file), localizer=spec.localizer,
            selection=spec.selection.config(),
            run_id=spec.run_id, min_robots=spec.min_robots, on_lost=spec.on_lost, rejoin=spec.rejoin, motion_time=spec.motion_time,
            step_timeout=spec.step_timeout, agents_per_process=spec.agents_per_process, world=spec.world,
            physics_params=spec.physics_params, physics_speed=spec.physics_speed),
        driver=DriverOptions(name=spec.driver, options=spec.driver_options, command_timeout=spec.command_timeout,
                             gateway_config=path(spec.gateway_config), emulator_events=path(spec.emulator_events),
                             ros2_robots=spec.ros2_robots),
        faults=FaultOptions(kill_robot=spec.kill_robot or None, standby=spec.standby, kill_coordinator=spec.kill_coordinator,
                            stall_coordinator=spec.stall_coordinator, stall_link=spec.stall_link, drop=spec.drop,
                            corrupt=spec.corrupt, delay=spec.delay),
        outputs=OutputOptions(command=spec.command, out=path(spec.out), result=path(spec.result), record=path(spec.record),
                              no_record=spec.no_record, on_record_error=spec.on_record_error, foxglove=spec.foxglove,
                              linger=spec.linger, ros2=spec.ros2, json=spec.json))


def launch_spec(options: LaunchOptions) -> LaunchSpec:
    """The launch spec of ``options``, every field (``launch_options`` of it gives them back; ``inchworm.Swarm``'s child
    process runs it)."""
    s, d, f, o = options.swarm, options.driver, options.faults, options.outputs

    def text(path: object) -> str | None:
        return None if path is None else str(path)

    return LaunchSpec(
        model=s.model, model_file=text(s.model_file), localizer=s.localizer, selection=selection_spec(s.selection), trajectory=text(s.trajectory),
        robots=s.robots, configs=s.configs, trajectory_seed=s.trajectory_seed, method=s.method, seed=s.seed, run_id=s.run_id,
        min_robots=s.min_robots, on_lost=s.on_lost, rejoin=s.rejoin, motion_time=s.motion_time, step_timeout=s.step_timeout,
        agents_per_process=s.agents_per_process, world=s.world, physics_params=s.physics_params, physics_speed=s.physics_speed,
        driver=d.name, driver_options=d.options, command_timeout=d.command_timeout, gateway_config=text(d.gateway_config),
        emulator_events=text(d.emulator_events), ros2_robots=d.ros2_robots,
        kill_robot=tuple(f.kills), standby=f.standby, kill_coordinator=f.kill_coordinator, stall_coordinator=f.stall_coordinator,
        stall_link=f.stall_link, drop=f.drop, corrupt=f.corrupt, delay=f.delay,
        command=o.command, out=text(o.out), result=text(o.result), record=text(o.record), no_record=o.no_record,
        on_record_error=o.on_record_error, foxglove=o.foxglove, linger=o.linger, ros2=o.ros2, json=o.json)
