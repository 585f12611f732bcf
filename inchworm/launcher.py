"""A whole distributed run on this host (``swarm launch`` / ``swarm demo``): ``launch(LaunchOptions(...))``.

The launcher opens the run's Zenoh router hub itself on a free loopback port, writes the
trajectory to a temporary file, starts one ``swarm agent`` process per robot (initial true pose
from the trajectory), or one per ``agents_per_process`` robots (default: one per robot up to
``ONE_PER_PROCESS_UP_TO`` robots, larger swarms in processes of at most ``AGENTS_PER_PROCESS``; driver
``ros2`` without ``kill_robot``: processes of at most ``AGENTS_PER_PROCESS`` from the start, one DDS participant each),
then ``swarm coordinator``, and waits for the coordinator, whose summary appears on stdout; the
coordinator writes the Fig. 13/14/17 plots to ``out`` and records the run (``record``, default
``recordings/<run>.mcap``; ``no_record``). On exit, error or Ctrl-C it stops every child it
started by its pid (SIGTERM, then SIGKILL after a grace period), so no process outlives it; the
result's status is the coordinator's. While it runs it keeps the run file of the run
(``runtime.wire.run_file``), so ``swarm estop --run RUN`` needs no ``--hub``; a run id already
live on this host is refused. Every input is checked before a process is started
(``check_before_start``).

``driver="gateway"`` runs the hardware path end to end without hardware: ``swarm emulate-robots``
(robots speaking the frame protocol on ptys) and, as on a gateway PC, one agent process per port of the
gateway config (``gateway_config``, default: ports of 5 robots each) running the port's link and the
agents of its robots with the gateway driver (``swarm agent --link``); with ``agents_per_process``, one
``swarm link`` process per port and the agents as for the other drivers. Ctrl-C
(or SIGTERM, SIGHUP; each child also stops itself if the launcher is killed: ``inchworm.lifeline``)
first publishes an ``EmergencyStop`` (waiting for every agent's acknowledgement) to the run, then
stops every child; so does a coordinator that ends with an error or is killed. ``driver="package.module:Class"`` (or
``file.py:Class``, an entry point name) starts the agents with a lab's own driver (docs/drivers.md);
one that is not ``simulated`` gets a coordinator with ``--no-truth``. ``driver="ros2"`` drives robots speaking
ROS 2 (docs/ros2.md): the lab's, or with ``ros2_robots`` simulated ones started first (``swarm ros2 robots``, whose
ground truth the agents then read, so the run has truths); ``ros2`` also runs the live bridge
(``swarm ros2 bridge``), and both are stopped after the agents.

Fault injection: ``kill_robot=(ID, STEP)`` (or several such pairs) SIGKILLs the agent process of robot ID (with the
gateway's port processes: the port's link and agents) at the first command of global step STEP and times the
coordinator's targeted ``EmergencyStop`` (the JSON object gets ``"kill": {"robot", "step", "detect_ms", "estop_ms"}``
of the first pair and ``"kills"``, one such object per pair, None for a step the run never reached); ``standby`` also starts a
standby coordinator, and ``kill_coordinator=STEP`` SIGKILLs the coordinator at STEP and times the
takeover (``"coordinator_kill": {"step", "takeover_ms"}``). ``stall_coordinator=(STEP, SECONDS)`` SIGSTOPs the
coordinator at STEP and SIGCONTs it SECONDS later (``"coordinator_stall": {"step", "stall_s"}``); beyond the Zenoh
lease a standby takes over and the stalled coordinator steps down (exit 4): the launcher then waits for the standby.
``stall_link=(STEP, SECONDS)`` does the same to the process serving the first port's link (``--driver gateway``:
the port process, or its ``swarm link`` process with ``agents_per_process``; ``"link_stall": {"step", "stall_s"}``).
"""

from __future__ import annotations

import contextlib
import json
import os
import queue
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from msgspec.structs import replace

from coordinator.node.process import EXIT_OUTPUT, default_recording
from coordinator.node.stop import StopSignals, collect_acks, publish_estop
from inchworm.launch_options import (
    DriverOptions as DriverOptions,
    FaultOptions as FaultOptions,
    LaunchOptions as LaunchOptions,
    OutputOptions as OutputOptions,
    SwarmOptions as SwarmOptions,
)
from inchworm.lifeline import Lifeline
from inchworm.limits import check_swarm_size
from inchworm.processes import (
    AGENTS_PER_PROCESS,
    GRACE_S,
    AgentErrors,
    CoordinatorKiller,
    ProcessStaller,
    RobotKiller,
    agents_per_process,
    default_gateway,
    start_agents,
    start_gateway,
    start_port_hosts,
    stop_all,
    wait_for_standby,
)
from inchworm.spawn import Spawned
from inchworm.specs import AgentHostSpec, CoordinatorSpec, EmulatorSpec, Ros2BridgeSpec, Ros2RobotsSpec, selection_spec
from robot_agent.assembly import driver_options
from robot_agent.emulator_process import check_radio_faults
from robot_agent.plugins import BUILT_IN, driver_class
from runtime.errors import OptionError, SwarmInputError
from runtime.gateway.config import GatewayConfig
from runtime.models.trajectory import Trajectory, body_spacing, random_trajectory, validate_connected, validate_passable
from runtime.paths import StrPath
from runtime.recording.mcap_log import is_finished
from runtime.wire.keys import estop_ack_key, validate_run
from runtime.wire.messages import EmergencyStop
from runtime.wire.run_file import published_run
from runtime.wire.transport import open_loopback_hub, subscribe_queue

if TYPE_CHECKING:
    pass

EXIT_STEPPED_DOWN = 4  # swarm coordinator's status when another coordinator holds the run (it stepped down or never began)
COORDINATOR_GRACE_S = 20.0  # s the coordinator gets to finish its recording after SIGTERM
ESTOP_ACK_S = 2.0  # s the launcher waits for every agent to acknowledge its run-wide stop before it stops them
DEFAULT_STEP_TIMEOUT_S = 5.0
START_S_PER_ROBOT = 0.1  # the coordinator waits this long per robot (at least 30 s) for every agent: 500 took 22-30 s on a busy 2-core machine
Say = Callable[[str], None]


@dataclass(frozen=True)
class LaunchResult:
    """How a launched run ended: ``status`` (the exit status of ``swarm launch``: 0, 3 robots lost or the run stopped,
    4, 5 an output failed, 128 + N killed by signal N; docs/development.md), its ``run_id``, its ``recording`` and the
    run's JSON object (``to_json()``: the keys ``swarm launch --json`` prints; None when the coordinator ended before
    it, or when it was not captured)."""

    status: int
    run_id: str
    recording: Path | None
    summary: dict[str, Any] | None

    @property
    def ok(self) -> bool:
        return self.status == 0

    @property
    def pf(self) -> float | None:
        """P_f (Eq. 24) of the run (None without ground truth or without a summary)."""
        return None if self.summary is None else self.summary.get("pf")

    @property
    def lost(self) -> list[int]:
        """The robots lost during the run."""
        return [] if self.summary is None else [int(x["robot"]) for x in self.summary.get("lost", [])]

    def to_json(self) -> dict[str, Any]:
        """The ``swarm launch --json`` object ({} when there is none)."""
        return dict(self.summary or {})


def _stderr(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def _stdout_json(obj: object) -> None:
    print(json.dumps(obj, separators=(",", ":")), flush=True)


def _wait_for(coordinator: subprocess.Popen[Any], agents: list[subprocess.Popen[Any]], errors: AgentErrors) -> int | str:
    """The coordinator's exit status, or the error line of an agent process that exited 2 first (its driver failed to
    start, ...: the coordinator would wait for it until its start timeout)."""
    while True:
        try:
            return coordinator.wait(timeout=0.1)
        except subprocess.TimeoutExpired:
            failure = errors.failure(agents)
            if failure is not None:
                return failure


def plugin_spec(spec: str) -> str:
    """A driver as the agents get it: a ``file.py:Class`` path made absolute (they may start elsewhere)."""
    module, sep, attr = spec.rpartition(":")
    return f"{Path(module).resolve()}:{attr}" if sep and module.endswith(".py") else spec


def _forward_output(stream: Iterable[str], last_json: list[str]) -> None:
    """Copy the coordinator's stdout to ours, holding back its last line (the JSON object, amended at the end)."""
    held = None
    for line in stream:
        if held is not None:
            sys.stdout.write(held)
            sys.stdout.flush()
        held = line
    if held is not None:
        last_json.append(held)


def check_writable(folder: Path, parameter: str, value: StrPath, options: object | None = None) -> None:
    """``OptionError`` naming ``parameter`` and its ``value`` (the command line: its flag, from ``options``) unless a
    file can be created in ``folder`` (created if missing)."""
    folder = folder if folder != Path("") else Path(".")
    if folder.exists() and not folder.is_dir():
        raise OptionError(parameter, f"{value}: {folder} is not a folder", options)
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=folder):
            pass
    except OSError as exc:
        raise OptionError(parameter, f"{value}: cannot write in {folder}: {exc.strerror or exc}", options) from None


def launch_trajectory(o: LaunchOptions) -> Trajectory:
    """The run's trajectory: the file, else a random one (``SwarmInputError`` for a swarm too small or too large)."""
    if o.swarm.trajectory:
        traj = Trajectory.load(o.swarm.trajectory)
        check_swarm_size(traj.n, str(o.swarm.trajectory), launched=True, parameter="trajectory")
        return traj
    return random_trajectory(o.swarm.robots, o.swarm.configs, np.random.default_rng(o.swarm.trajectory_seed),
                             sensing_range=o.swarm.model.sensing_range_m,
                             **body_spacing(o.swarm.model))


def check_before_start(o: LaunchOptions, traj: Trajectory, run_id: str, out: Path) -> None:
    """Everything that can fail before a process is started: the run id, the trajectory, the strategy
    options, the recording, plot and result folders, the Foxglove extra and port; each error names the flag."""
    from coordinator.localization import make_localizer  # noqa: PLC0415 - scipy, only when launching
    from coordinator.strategies import make_strategy  # noqa: PLC0415
    from runtime.recording.foxglove_live import require_foxglove  # noqa: PLC0415

    try:
        validate_run(run_id)
    except SwarmInputError as exc:
        raise OptionError("run_id", f"{run_id!r}: {exc}", o.swarm) from None
    validate_connected(traj, o.swarm.model.sensing_range_m)
    validate_passable(traj, o.swarm.model)
    make_strategy(o.swarm.method, traj.n, o.swarm.model, make_localizer(o.swarm.localizer, o.swarm.model), o.swarm.selection, o.swarm.seed)
    if not o.outputs.no_record:
        record = Path(o.outputs.record or default_recording(run_id))
        check_writable(record.parent, "record", record, o.outputs)
    check_writable(out, "out", out, o.outputs)
    if o.outputs.result:
        check_writable(Path(o.outputs.result).parent, "result", o.outputs.result, o.outputs)
    if o.outputs.foxglove is not None:
        require_foxglove()
        with socket.socket() as probe:
            try:
                probe.bind(("127.0.0.1", o.outputs.foxglove))
            except OSError as exc:
                port = o.outputs.foxglove
                raise OptionError("foxglove", f"{port}: cannot serve on 127.0.0.1:{port}: {exc.strerror or exc}") from None
    if o.driver.name == "gateway" and o.driver.gateway_config:
        radius = GatewayConfig.load(o.driver.gateway_config).limits.robot_radius_m
        if radius != o.swarm.model.robot_radius_m:
            raise OptionError("robot_radius", f"{o.swarm.model.robot_radius_m:g} (of the model) differs from the robots' body radius "
                              f"{radius:g} m in {o.driver.gateway_config} (limits.robot_radius_m): plan with the robots' own bodies")
    if o.driver.name not in BUILT_IN:
        driver_class(o.driver.name)
        driver_options(list(o.driver.options))
    if o.swarm.world == "physics":
        from runtime.world.params import parse_physics_params  # noqa: PLC0415 - the physics extra, only when asked for
        from runtime.world.physics import require_pymunk  # noqa: PLC0415

        require_pymunk()
        parse_physics_params(list(o.swarm.physics_params), o.swarm.model)
        if o.driver.name not in ("sim", "gateway") and not o.driver.ros2_robots:
            raise OptionError("world", f"physics drives simulated or emulated robots: it needs the driver sim or gateway, "
                              f"or ros2 with ros2_robots, got {o.driver.name}", o.swarm)
        if o.swarm.motion_time:
            raise OptionError("motion_time", "is the noise model's motion time: in the physics world the wheels take the time", o.swarm)
        if o.driver.name == "sim" and o.swarm.agents_per_process not in (None, traj.n):
            raise OptionError("agents_per_process", f"must be the {traj.n} robots of the run (or left out) in the physics world "
                              f"(one world, stepped in one agent process), got {o.swarm.agents_per_process}", o.swarm)
    elif o.swarm.physics_params:
        raise OptionError("physics_params", "only applies to the physics world (world physics)", o.swarm)
    if o.driver.ros2_robots and o.driver.name != "ros2":
        raise OptionError("ros2_robots", "starts simulated ROS 2 robots for the ROS 2 driver: it needs the driver ros2", o.driver)
    if o.driver.name == "ros2" or o.outputs.ros2:
        from runtime.wire.ros2 import require_ros2  # noqa: PLC0415 - ROS 2 only for ROS 2 runs

        require_ros2(f"swarm {o.outputs.command} --driver ros2" if o.driver.name == "ros2" else f"swarm {o.outputs.command} --ros2")
    if o.driver.name == "ros2":
        ros2_settings(o)
    for robot, step in o.faults.kills:
        if robot not in traj.ids:
            raise OptionError("kill_robot", f"{robot}@{step}: robot {robot} is not one of the run's robots {traj.ids.tolist()}", o.faults)


def ros2_settings(o: LaunchOptions) -> tuple[list[str], bool]:
    """The ROS 2 driver's options of the agents (with ``ros2_robots``: their ground truth), and whether the
    robots publish a ground truth (then the run has truths: P_f and contacts)."""
    from robot_agent.ros2_config import Ros2Config  # noqa: PLC0415 - only for ROS 2 runs

    options = list(o.driver.options)
    if o.driver.ros2_robots and not Ros2Config.load(driver_options(options)).ground_truth:
        options.append("ground_truth=ground_truth")
    if o.driver.ros2_robots and o.swarm.world == "physics":
        options = wheel_limits(o, options) + options
    return options, bool(Ros2Config.load(driver_options(options)).ground_truth)


def wheel_limits(o: LaunchOptions, options: list[str]) -> list[str]:
    """The driver's speed and acceleration limits the physical world's wheels reach (``--physics-param``), for those of
    ``options`` (and their config file) left at the defaults: the driver must not count on speeds the wheels cannot give."""
    from robot_agent.ros2_config import Ros2Config  # noqa: PLC0415 - only for ROS 2 runs
    from runtime.world.params import parse_physics_params  # noqa: PLC0415 - the physics extra, only when asked for

    params, given, default = parse_physics_params(list(o.swarm.physics_params), o.swarm.model), Ros2Config.load(driver_options(options)), Ros2Config()
    half = params.track_m / 2.0
    wanted = {"max_linear_speed": params.max_wheel_speed_m_s, "linear_accel": params.max_wheel_accel_m_s2,
              "max_angular_speed": params.max_wheel_speed_m_s / half, "angular_accel": params.max_wheel_accel_m_s2 / half}
    return [f"{name}={limit!r}" for name, limit in wanted.items()
            if getattr(given, name) == getattr(default, name) and getattr(default, name) > limit]


def ros2_step_timeout(options: list[str]) -> float:
    """The coordinator's step timeout for ROS 2 robots: the slowest motion the agents' default limits allow (turn pi,
    drive ``max_drive_m``) at the driver's speeds and accelerations, 1.5 times, plus the sensing window and 2 s."""
    from robot_agent.ros2_config import Ros2Config  # noqa: PLC0415 - only for ROS 2 runs
    from runtime.wire.messages import CommandLimits  # noqa: PLC0415

    cfg, limits = Ros2Config.load(driver_options(options)), CommandLimits()
    return max(DEFAULT_STEP_TIMEOUT_S, 1.5 * cfg.motion_time_s(limits.max_turn_rad, limits.max_drive_m) + cfg.sensing_window_s + 2.0)


def stop_answers(acks: queue.Queue[tuple[str, bytes]], stamp_ns: int, until: float,
                 hosts: dict[int, subprocess.Popen[Any]]) -> tuple[set[int], set[int]]:
    """The robots whose agents acknowledged the stop stamped ``stamp_ns`` and those whose agent process (``hosts``: robot ->
    its process) had exited without acknowledging (a Ctrl-C reaches the agents too: they stop with it); waits until
    every robot is one or the other, or monotonic time ``until``."""
    heard: set[int] = set()
    while True:
        exited = {robot for robot, proc in hosts.items() if proc.poll() is not None} - heard
        if len(heard | exited) >= len(hosts) or time.monotonic() >= until:
            return heard, exited
        got = collect_acks(acks, stamp_ns, min(until, time.monotonic() + 0.05))
        heard |= {int(name) for by, name in got if by == "agent"}


def stop_text(run_id: str, heard: int, exited: int, robots: int) -> str:
    """What the launcher says of its run-wide stop: acknowledged by ``heard`` agents, ``exited`` had exited already."""
    if exited == robots:
        return f"emergency stop sent to run {run_id}; its {robots} agents had already exited (a stop signal reached them too)"
    gone = f"; the other {exited} had already exited" if exited and heard + exited == robots else (
        f"; {exited} had already exited" if exited else "")
    return f"emergency stop sent to run {run_id} (acknowledged by {heard} of {robots} agents{gone})"


def launch(o: LaunchOptions, *, say: Say = _stderr, emit_json: Callable[[object], None] = _stdout_json, capture: bool = True) -> LaunchResult:
    """Run it (module doc) and return its ``LaunchResult``: the exit status (the coordinator's, 128 + N if it was
    killed by signal N) and, with ``capture`` (or ``json``), the run's JSON object, read from the coordinator's
    last line of output (the other lines are passed on to stdout as they come). ``say``: the launcher's notes
    (stderr); ``emit_json``: prints the JSON object when ``json`` (amended with the kills and stalls)."""
    check_radio_faults(o.faults.drop, o.faults.corrupt, o.faults.delay)
    traj = launch_trajectory(o)
    if not 2 <= o.swarm.min_robots <= traj.n:
        raise OptionError("min_robots", f"must be between 2 and the {traj.n} robots of the run, got {o.swarm.min_robots}", o.swarm)
    per_process = traj.n if o.swarm.world == "physics" and o.driver.name == "sim" else agents_per_process(traj.n, o.swarm.agents_per_process)
    if o.driver.name == "ros2" and o.swarm.agents_per_process is None and o.faults.kill_robot is None:  # one DDS participant for up to 50 robots
        processes = -(-traj.n // AGENTS_PER_PROCESS)
        per_process = -(-traj.n // processes)
    port_hosts = o.driver.name == "gateway" and o.swarm.agents_per_process is None  # the gateway PC's layout (``start_port_hosts``)
    run_id = o.swarm.run_id or f"launch-{os.getpid()}"
    out = Path(o.outputs.out or Path("out") / o.outputs.command)
    check_before_start(o, traj, run_id, out)
    procs: list[subprocess.Popen[Any]] = []
    gateway_procs = 0  # procs[0] the emulator, then one link per port (--driver gateway)
    coordinators: list[subprocess.Popen[Any]] = []  # the coordinator and its standby, stopped first
    ros2_procs: list[subprocess.Popen[Any]] = []  # simulated ROS 2 robots and the bridge, stopped after the agents
    signals = StopSignals()  # Ctrl-C / SIGTERM / SIGHUP: estop, then every child stopped; never interrupts the stopping
    lifeline = Lifeline()  # every child ends with this process, even after SIGKILL
    agent_errors = AgentErrors()  # the agents' stderr, their error lines kept back (one line if one cannot start)
    tied = lifeline.child_options()

    def stop_children() -> None:
        """Coordinator, agents, links, emulator: in this order, while the hub still routes (called twice: idempotent)."""
        with signals.deferred():
            if coordinators:  # first, with time to finish their recordings
                stop_all(coordinators, COORDINATOR_GRACE_S)
            stop_all(procs[gateway_procs:])  # the agents, before the links they talk through (no "link gone" at the end)
            stop_all(ros2_procs)
            stop_all(procs[1:gateway_procs])  # the links, before the emulator whose ptys they read
            stop_all(procs[:1] if gateway_procs else [])

    try:
        with contextlib.ExitStack() as stack:
            tmp = stack.enter_context(tempfile.TemporaryDirectory(prefix="swarm-launch-"))
            hub_session, _, hub = open_loopback_hub()  # (a port another process takes meanwhile is replaced)
            stack.enter_context(hub_session)
            stack.enter_context(published_run(run_id, hub, f"swarm {o.outputs.command}"))
            stack.callback(stop_children)  # before the hub closes
            lifeline.guard(Path(tmp))
            _acks_sub, acks = subscribe_queue(hub_session, estop_ack_key(run_id))

            def stop_run(reason: str) -> str:
                """The run-wide stop, waiting (at most ``ESTOP_ACK_S``) until every agent acknowledged it or has exited."""
                stop = EmergencyStop(run=run_id, step=0, source=f"swarm {o.outputs.command} (pid {os.getpid()})", reason=reason)
                sent = publish_estop(hub_session, stop)
                heard, exited = stop_answers(acks, stop.stamp_ns, sent[0] + ESTOP_ACK_S, agent_procs)
                return stop_text(run_id, len(heard), len(exited), traj.n)

            traj_file = Path(tmp) / "trajectory.json"
            traj.save(traj_file)
            agent = AgentHostSpec(run_id=run_id, robots=(), hub=hub, seed=o.swarm.seed, model=o.swarm.model, motion_time=o.swarm.motion_time)
            if o.driver.name not in BUILT_IN:
                agent = replace(agent, driver=plugin_spec(o.driver.name), driver_options=o.driver.options, command_timeout=o.driver.command_timeout)
            if o.swarm.world == "physics" and o.driver.name == "sim":  # the agent process steps the world
                agent = replace(agent, world="physics", physics_params=o.swarm.physics_params, physics_speed=o.swarm.physics_speed)
            truth = o.driver.name in BUILT_IN or driver_class(o.driver.name).simulated
            step_timeout = DEFAULT_STEP_TIMEOUT_S if o.swarm.step_timeout is None else o.swarm.step_timeout
            if o.driver.name == "ros2":
                ros2_options, truth = ros2_settings(o)
                if o.swarm.step_timeout is None:
                    step_timeout = ros2_step_timeout(ros2_options)
                if not truth:
                    say(f"swarm {o.outputs.command}: the ROS 2 robots' settings name no ground truth (--driver-option ground_truth=TOPIC, "
                        f"e.g. ground_truth of swarm ros2 robots): the run has no true poses, so no P_f and no contacts")
                agent = replace(agent, driver="ros2", driver_options=tuple(ros2_options))
                if o.driver.ros2_robots:  # the same settings: namespaces, frame, topics
                    sim_robots = Ros2RobotsSpec(trajectory=str(traj_file), seed=o.swarm.seed, model=o.swarm.model, driver_options=tuple(ros2_options))
                    if o.swarm.world == "physics":  # its contacts, stalls and still poses go to the run's record
                        sim_robots = replace(sim_robots, world="physics", physics_params=o.swarm.physics_params, run_id=run_id, hub=hub)
                    ros2_procs.append(Spawned(sim_robots, **tied))
            if o.outputs.ros2:
                ros2_procs.append(Spawned(Ros2BridgeSpec(run_id=run_id, hub=hub, trajectory=str(traj_file),
                                                         robot_radius=o.swarm.model.robot_radius_m), **tied))
            if o.driver.name == "gateway":
                gateway = GatewayConfig.load(o.driver.gateway_config) if o.driver.gateway_config else \
                    default_gateway(traj, robot_radius=o.swarm.model.robot_radius_m)
                missing = sorted(set(int(i) for i in traj.ids) - set(gateway.robots))
                if missing:
                    raise SwarmInputError(f"robots {missing} of the trajectory are behind no port of the gateway config")
                physics, f = o.swarm.world == "physics", o.faults
                emulator = EmulatorSpec(config="", trajectory=str(traj_file), seed=o.swarm.seed, motion_time=o.swarm.motion_time,
                                        model=o.swarm.model, physics=physics, physics_params=o.swarm.physics_params if physics else (),
                                        physics_speed=o.swarm.physics_speed if physics else 0.0, drop=f.drop, corrupt=f.corrupt,
                                        delay=f.delay, events=None if o.driver.emulator_events is None else str(o.driver.emulator_events),
                                        hub=hub, run_id=run_id)
                live = start_gateway(gateway, Path(tmp), emulator, procs, links=not port_hosts, **tied)
                gateway_procs = len(procs)
                agent = replace(agent, driver="gateway", gateway_config=str(live))
            first = len(procs)
            piped = {**tied, **agent_errors.popen_kwargs()}
            try:
                if port_hosts:  # one process per port: its link and its robots' agents
                    agent_procs = start_port_hosts(traj, live, agent, procs, traj_file, **piped)
                else:
                    start_agents(traj, agent, procs, per_process, traj_file, **piped)
                    agent_procs = {int(robot): procs[first + k // per_process] for k, robot in enumerate(traj.ids)}  # its hosting process
            finally:
                agent_errors.watch(procs[first:])
            agent_list = procs[first:]
            recording = None if o.outputs.no_record else (o.outputs.record or default_recording(run_id))
            json_hold = o.outputs.json or capture  # the coordinator's JSON object: held back, amended, returned
            s, out_o = o.swarm, o.outputs
            coordinator_spec = CoordinatorSpec(
                trajectory=str(traj_file), run_id=run_id, hub=hub, method=s.method, seed=s.seed, localizer=s.localizer, model=s.model,
                model_file=None if s.model_file is None else str(s.model_file), selection=selection_spec(s.selection),
                start_timeout=max(30.0, START_S_PER_ROBOT * traj.n), step_timeout=step_timeout, on_lost=s.on_lost, min_robots=s.min_robots,
                truth=truth, result=None if out_o.result is None else str(out_o.result), out=str(out), rejoin=s.rejoin,
                record=None if recording is None else str(recording), no_record=recording is None, on_record_error=out_o.on_record_error,
                foxglove=out_o.foxglove, linger=out_o.linger if out_o.foxglove is not None else None, json=json_hold,
                command=f"swarm {out_o.command} (run {run_id}, {traj.n} robots, method {s.method}, seed {s.seed})")
            what = {"sim": "agents", "gateway": "gateway agents + emulated robots",
                    "ros2": "ROS 2 agents" + (" + simulated ROS 2 robots" if o.driver.ros2_robots else "")
                    }.get(o.driver.name, f"agents ({o.driver.name})")
            what += " in the physical world" if o.swarm.world == "physics" else ""
            hosts = "" if per_process == 1 and not port_hosts else f" in {len(set(map(id, agent_procs.values())))} processes"
            say(f"swarm {o.outputs.command}: {traj.n} {what}{hosts} + coordinator, run {run_id}, hub {hub} "
                f"(emergency stop: swarm estop --run {run_id})")
            killed: dict[int, int] = {}  # pid -> when it was killed: robots hosted by one process die together
            killers = [RobotKiller(hub_session, run_id, robot, step, agent_procs[robot], killed) for robot, step in o.faults.kills]
            stallers: dict[str, ProcessStaller] = {}
            if o.faults.stall_link is not None:
                first_port = GatewayConfig.load(live).ports[0]
                link_proc = agent_procs[first_port.robots[0]] if port_hosts else procs[1]
                stallers["link_stall"] = ProcessStaller(hub_session, run_id, *o.faults.stall_link, link_proc)
            standby = None
            if o.faults.standby:
                standby_spec = replace(coordinator_spec, standby=True,
                                       record=None if recording is None else str(Path(recording).with_suffix(".standby.mcap")))
                standby = Spawned(standby_spec, stdout=subprocess.PIPE if json_hold else None, text=True, **tied)
                coordinators.append(standby)
                procs.append(standby)
                wait_for_standby(hub_session, run_id, standby)
            coordinator = Spawned(coordinator_spec, stdout=subprocess.PIPE if json_hold else None, text=True, **tied)
            coordinators.insert(0, coordinator)  # before its standby (which then sees the run stopped)
            procs.append(coordinator)
            coord_killer = None if o.faults.kill_coordinator is None else \
                CoordinatorKiller(hub_session, run_id, o.faults.kill_coordinator, coordinator)
            if o.faults.stall_coordinator is not None:
                stallers["coordinator_stall"] = ProcessStaller(hub_session, run_id, *o.faults.stall_coordinator, coordinator)
            last: list[str] = []
            forwarders = [threading.Thread(target=_forward_output, args=(p.stdout, last), daemon=True)
                          for p in (coordinator, standby) if json_hold and p is not None]
            for forwarder in forwarders:
                forwarder.start()
            try:
                status = _wait_for(coordinator, agent_list, agent_errors)
                if isinstance(status, str):  # an agent could not start (no command was sent): its one line, every child stopped
                    raise SwarmInputError(status)
                if standby is not None and status < 0:  # died without a word: the standby takes the run over
                    say(f"swarm {o.outputs.command}: the coordinator was killed (signal {-status}); the standby takes over")
                    status = standby.wait()
                elif standby is not None and status == EXIT_STEPPED_DOWN:  # it stalled past its lease: the standby holds the run
                    say(f"swarm {o.outputs.command}: the coordinator stepped down (another coordinator holds the run); waiting for the standby")
                    status = standby.wait()
            except KeyboardInterrupt:
                say(f"swarm {o.outputs.command}: interrupted: {stop_run('the launcher was interrupted')}")
                raise
            if status not in (0, EXIT_OUTPUT):  # an abort, an error or a killed coordinator: stop every robot
                done = stop_run(f"the coordinator exited with status {status}")
                say(f"swarm {o.outputs.command}: the coordinator exited with status {status}: {done}")
            if standby is not None:
                try:
                    standby.wait(timeout=GRACE_S)  # it saw the run finish (or stop) and exits by itself
                except subprocess.TimeoutExpired:
                    stop_all([standby], COORDINATOR_GRACE_S)
            for forwarder in forwarders:
                forwarder.join(timeout=10)
            kills = [killer.report() for killer in killers]
            for kill in kills:
                if kill is None:
                    continue
                say(f"swarm {o.outputs.command}: killed the agent of robot {kill['robot']} at step {kill['step']}; its emergency "
                    f"stop was sent {kill['detect_ms']} ms and heard {kill['estop_ms']} ms after the kill")
            coord_kill = None if coord_killer is None else coord_killer.report()
            if coord_kill is not None:
                say(f"swarm {o.outputs.command}: killed the coordinator at step {coord_kill['step']}; the next coordinator's first "
                    f"command came {coord_kill['takeover_ms']} ms after the kill")
            stalls = {name: staller.report() for name, staller in stallers.items()}
            for name, stall in stalls.items():
                if stall is not None:
                    say(f"swarm {o.outputs.command}: stalled the {name.split('_')[0]} (SIGSTOP) at step {stall['step']} for {stall['stall_s']} s")
            summary: dict[str, Any] = {}
            if json_hold:
                for line in last:  # the last line of each coordinator: the one that finished the run is a JSON object
                    try:
                        summary = json.loads(line)
                    except json.JSONDecodeError:  # a coordinator that failed before its JSON line: pass it on as it was
                        sys.stdout.write(line)
                extra: dict[str, object] = {} if not killers else {"kill": kills[0], "kills": kills}
                if coord_killer is not None:
                    extra["coordinator_kill"] = coord_kill
                extra.update(stalls)
                if o.outputs.json and (summary or extra):
                    emit_json({**summary, **extra})
                summary = {**summary, **extra} if summary else {}
            if recording is not None and Path(recording).exists():
                say(f"swarm {o.outputs.command}: recording {recording}" if is_finished(recording) else
                    f"swarm {o.outputs.command}: recording {recording} is incomplete: the recording failed (what reached the disk: "
                    f"swarm info {recording}; swarm recover {recording})")
            return LaunchResult(status if status >= 0 else 128 - status, run_id,  # killed by signal N: 128 + N, as a shell reports it
                                None if recording is None else Path(recording), summary or None)
    finally:
        stop_children()
        for line in agent_errors.held():  # an agent's error that did not end the start: as it printed it
            say(line)
        lifeline.close()
        signals.restore()
