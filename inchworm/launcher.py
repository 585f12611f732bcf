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
import socket
import subprocess
import sys
import tempfile
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from coordinator.process import EXIT_OUTPUT, default_recording
from coordinator.stop import StopSignals, collect_acks, publish_estop
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
    radio_faults,
    start_agents,
    start_gateway,
    start_port_hosts,
    stop_all,
    wait_for_standby,
)
from robot_agent.assembly import driver_options
from robot_agent.plugins import BUILT_IN, driver_class
from runtime.errors import SwarmInputError
from runtime.gateway.config import GatewayConfig
from runtime.models.config import ModelConfig
from runtime.models.trajectory import Trajectory, body_spacing, random_trajectory, validate_connected, validate_passable
from runtime.recording.mcap_log import is_finished
from runtime.wire.keys import estop_ack_key, validate_run
from runtime.wire.messages import EmergencyStop
from runtime.wire.run_file import published_run
from runtime.wire.transport import free_tcp_port, loopback_hub, open_session, subscribe_queue

if TYPE_CHECKING:
    from coordinator.selection.selector import SelectionConfig

EXIT_STEPPED_DOWN = 4  # swarm coordinator's status when another coordinator holds the run (it stepped down or never began)
COORDINATOR_GRACE_S = 20.0  # s the coordinator gets to finish its recording after SIGTERM
ESTOP_ACK_S = 2.0  # s the launcher waits for every agent to acknowledge its run-wide stop before it stops them
DEFAULT_STEP_TIMEOUT_S = 5.0
START_S_PER_ROBOT = 0.1  # the coordinator waits this long per robot (at least 30 s) for every agent: 500 took 22-30 s on a busy 2-core machine
Say = Callable[[str], None]


@dataclass(frozen=True)
class LaunchOptions:
    """What ``launch`` runs. ``model`` / ``selection`` / ``localizer`` are checked before anything starts;
    ``model_flags`` and ``coordinator_flags`` (option name -> value, only those given) are passed on to the
    agent and coordinator processes as ``--name=value``. Times in seconds."""

    model: ModelConfig
    localizer: str
    selection: SelectionConfig
    command: str = "launch"  # how the launcher names itself (swarm launch / swarm demo)
    trajectory: Path | None = None  # else a random one of ``robots`` x ``configs`` (seed ``trajectory_seed``)
    robots: int = 10
    configs: int = 3
    trajectory_seed: int = 0
    method: str = "inchworm"
    seed: int = 0
    run_id: str | None = None  # default launch-<pid>
    out: Path | None = None  # default out/<command>
    result: Path | None = None
    motion_time: float = 0.0
    step_timeout: float | None = None  # None: DEFAULT_STEP_TIMEOUT_S, with driver "ros2" at least its slowest motion (``ros2_step_timeout``)
    driver: str = "sim"
    driver_options: tuple[str, ...] = ()
    command_timeout: float | None = None
    gateway_config: Path | None = None
    emulator_events: Path | None = None
    min_robots: int = 2
    kill_robot: tuple[int, int] | tuple[tuple[int, int], ...] | None = None  # one (ID, STEP) or several

    @property
    def kills(self) -> list[tuple[int, int]]:
        """Every ``(robot, step)`` of ``kill_robot``."""
        spec = self.kill_robot
        if not spec:
            return []
        if isinstance(spec[0], int):
            return [(int(spec[0]), int(spec[1]))]
        return [(int(robot), int(step)) for robot, step in spec]
    standby: bool = False
    kill_coordinator: int | None = None
    agents_per_process: int | None = None
    drop: float = 0.0
    corrupt: float = 0.0
    delay: float = 0.0
    record: Path | None = None
    no_record: bool = False
    foxglove: int | None = None
    linger: float | None = None
    json: bool = False
    model_flags: dict[str, Any] = field(default_factory=dict)
    coordinator_flags: dict[str, Any] = field(default_factory=dict)
    world: str = "model"  # or "physics": the simulated agents drive in the rigid-body world, all in one process (docs/physics.md)
    physics_params: tuple[str, ...] = ()  # --physics-param NAME=VALUE
    physics_speed: float = 0.0
    ros2: bool = False  # also run the live ROS 2 bridge (``swarm ros2 bridge``)
    ros2_robots: bool = False  # with driver "ros2": also start simulated ROS 2 robots (``swarm ros2 robots``)
    stall_coordinator: tuple[int, float] | None = None  # (STEP, SECONDS): SIGSTOP the coordinator at STEP, SIGCONT SECONDS later
    stall_link: tuple[int, float] | None = None  # the same for the process of the first port's link (--driver gateway)


def _stderr(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def _stdout_json(obj: object) -> None:
    print(json.dumps(obj, separators=(",", ":")), flush=True)


def flags(values: dict[str, Any]) -> list[str]:
    """``--name=value`` for each option (``=`` so negative numbers pass; repr so floats are exact)."""
    return [f"--{name.replace('_', '-')}={_arg_text(value)}" for name, value in values.items() if value is not None]


def _arg_text(value) -> str:
    return str(value) if isinstance(value, (str, Path)) else repr(value)


def _wait_for(coordinator: subprocess.Popen, agents: list[subprocess.Popen], errors: AgentErrors) -> int | str:
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


def _forward_output(stream, last_json: list[str]) -> None:
    """Copy the coordinator's stdout to ours, holding back its last line (the JSON object, amended at the end)."""
    held = None
    for line in stream:
        if held is not None:
            sys.stdout.write(held)
            sys.stdout.flush()
        held = line
    if held is not None:
        last_json.append(held)


def _check_writable(folder: Path, flag: str, value: Path) -> None:
    """``SwarmInputError`` naming ``flag value`` unless a file can be created in ``folder`` (created if missing)."""
    folder = folder if folder != Path("") else Path(".")
    if folder.exists() and not folder.is_dir():
        raise SwarmInputError(f"{flag} {value}: {folder} is not a folder")
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=folder):
            pass
    except OSError as exc:
        raise SwarmInputError(f"{flag} {value}: cannot write in {folder}: {exc.strerror or exc}") from None


def launch_trajectory(o: LaunchOptions) -> Trajectory:
    """The run's trajectory: the file, else a random one (``SwarmInputError`` for a swarm too small or too large)."""
    if o.trajectory:
        traj = Trajectory.load(o.trajectory)
        check_swarm_size(traj.n, f"--trajectory {o.trajectory}", launched=True)
        return traj
    if o.robots < 2 or o.configs < 1:
        raise SwarmInputError("a launched swarm needs -n >= 2 robots and --configs >= 1")
    return random_trajectory(o.robots, o.configs, np.random.default_rng(o.trajectory_seed), sensing_range=o.model.sensing_range_m,
                             **body_spacing(o.model))


def check_before_start(o: LaunchOptions, traj: Trajectory, run_id: str, out: Path) -> None:
    """Everything that can fail before a process is started: the run id, the trajectory, the strategy
    options, the recording, plot and result folders, the Foxglove extra and port; each error names the flag."""
    from coordinator.localization import make_localizer  # noqa: PLC0415 - scipy, only when launching
    from coordinator.strategies import make_strategy  # noqa: PLC0415
    from runtime.recording.foxglove_live import require_foxglove  # noqa: PLC0415

    try:
        validate_run(run_id)
    except SwarmInputError as exc:
        raise SwarmInputError(f"--run {run_id!r}: {exc}") from None
    validate_connected(traj, o.model.sensing_range_m)
    validate_passable(traj, o.model)
    make_strategy(o.method, traj.n, o.model, make_localizer(o.localizer, o.model), o.selection, o.seed)
    if not o.no_record:
        record = Path(o.record or default_recording(run_id))
        _check_writable(record.parent, "--record", record)
    _check_writable(out, "--out", out)
    if o.result:
        _check_writable(Path(o.result).parent, "--result", o.result)
    if o.foxglove is not None:
        require_foxglove()
        with socket.socket() as probe:
            try:
                probe.bind(("127.0.0.1", o.foxglove))
            except OSError as exc:
                raise SwarmInputError(f"--foxglove {o.foxglove}: cannot serve on 127.0.0.1:{o.foxglove}: {exc.strerror or exc}") from None
    if o.driver == "gateway" and o.gateway_config:
        radius = GatewayConfig.load(o.gateway_config).limits.robot_radius_m
        if radius != o.model.robot_radius_m:
            raise SwarmInputError(f"--robot-radius {o.model.robot_radius_m:g} differs from the robots' body radius {radius:g} m "
                                  f"in {o.gateway_config} (limits.robot_radius_m): plan with the robots' own bodies")
    if o.driver not in BUILT_IN:
        driver_class(o.driver)
        driver_options(list(o.driver_options))
    if o.world == "physics":
        from runtime.world.params import parse_physics_params  # noqa: PLC0415 - the physics extra, only when asked for
        from runtime.world.physics import require_pymunk  # noqa: PLC0415

        require_pymunk()
        parse_physics_params(list(o.physics_params), o.model)
        if o.driver not in ("sim", "gateway"):
            raise SwarmInputError(f"--world physics drives simulated or emulated robots: it needs --driver sim or gateway, got --driver {o.driver}")
        if o.motion_time:
            raise SwarmInputError("--motion-time is the noise model's motion time: in --world physics the wheels take the time")
        if o.driver == "sim" and o.agents_per_process not in (None, traj.n):
            raise SwarmInputError(f"--world physics steps one world in one agent process: --agents-per-process must be the "
                                  f"{traj.n} robots of the run (or left out), got {o.agents_per_process}")
    elif o.physics_params:
        raise SwarmInputError("--physics-param sets the physical world: it needs --world physics")
    if o.ros2_robots and o.driver != "ros2":
        raise SwarmInputError("--ros2-robots starts simulated ROS 2 robots for the ROS 2 driver: it needs --driver ros2")
    if o.driver == "ros2" or o.ros2:
        from runtime.wire.ros2 import require_ros2  # noqa: PLC0415 - ROS 2 only for ROS 2 runs

        require_ros2(f"swarm {o.command} --driver ros2" if o.driver == "ros2" else f"swarm {o.command} --ros2")
    if o.driver == "ros2":
        ros2_settings(o)
    if o.kill_coordinator is not None and o.kill_coordinator < 1:
        raise SwarmInputError(f"--kill-coordinator {o.kill_coordinator}: the step must be >= 1")
    for flag, stall in (("--stall-coordinator", o.stall_coordinator), ("--stall-link", o.stall_link)):
        if stall is not None and (stall[0] < 1 or not stall[1] > 0):
            raise SwarmInputError(f"{flag} {stall[0]}:{stall[1]:g}: the step must be >= 1 and the seconds > 0")
    if o.stall_link is not None and o.driver != "gateway":
        raise SwarmInputError("--stall-link stalls a link process: it needs --driver gateway")
    for robot, step in o.kills:
        if robot not in traj.ids:
            raise SwarmInputError(f"--kill-robot {robot}@{step}: robot {robot} is not one of the run's robots {traj.ids.tolist()}")


def ros2_settings(o: LaunchOptions) -> tuple[list[str], bool]:
    """The ROS 2 driver's options of the agents (with ``ros2_robots``: their ground truth), and whether the
    robots publish a ground truth (then the run has truths: P_f and contacts)."""
    from robot_agent.ros2_config import Ros2Config  # noqa: PLC0415 - only for ROS 2 runs

    options = list(o.driver_options)
    if o.ros2_robots and not Ros2Config.load(driver_options(options)).ground_truth:
        options.append("ground_truth=ground_truth")
    return options, bool(Ros2Config.load(driver_options(options)).ground_truth)


def ros2_step_timeout(options: list[str]) -> float:
    """The coordinator's step timeout for ROS 2 robots: the slowest motion the agents' default limits allow (turn pi,
    drive ``max_drive_m``) at the driver's speeds and accelerations, 1.5 times, plus the sensing window and 2 s."""
    from robot_agent.ros2_config import Ros2Config  # noqa: PLC0415 - only for ROS 2 runs
    from runtime.wire.messages import CommandLimits  # noqa: PLC0415

    cfg, limits = Ros2Config.load(driver_options(options)), CommandLimits()
    return max(DEFAULT_STEP_TIMEOUT_S, 1.5 * cfg.motion_time_s(limits.max_turn_rad, limits.max_drive_m) + cfg.sensing_window_s + 2.0)


def launch(o: LaunchOptions, *, say: Say = _stderr, emit_json: Callable[[object], None] = _stdout_json) -> int:
    """Run it (module doc); the exit status: the coordinator's, 128 + N if it was killed by signal N.
    ``say``: the launcher's notes (stderr); ``emit_json``: the amended JSON object of a run with a kill."""
    faults = radio_faults(o.drop, o.corrupt, o.delay)
    if o.driver != "gateway" and (o.drop or o.corrupt or o.delay):
        raise SwarmInputError("--drop, --corrupt and --delay are faults of the emulated radio: they need --driver gateway")
    traj = launch_trajectory(o)
    if not 2 <= o.min_robots <= traj.n:
        raise SwarmInputError(f"--min-robots {o.min_robots}: must be between 2 and the {traj.n} robots of the run")
    per_process = traj.n if o.world == "physics" and o.driver == "sim" else agents_per_process(traj.n, o.agents_per_process)
    if o.driver == "ros2" and o.agents_per_process is None and o.kill_robot is None:  # one DDS participant for up to 50 robots
        processes = -(-traj.n // AGENTS_PER_PROCESS)
        per_process = -(-traj.n // processes)
    port_hosts = o.driver == "gateway" and o.agents_per_process is None  # the gateway PC's layout (``start_port_hosts``)
    run_id = o.run_id or f"launch-{os.getpid()}"
    out = o.out or Path("out") / o.command
    check_before_start(o, traj, run_id, out)
    port = free_tcp_port()
    hub_settings, _ = loopback_hub(port)
    hub = f"tcp/127.0.0.1:{port}"
    py = sys.executable
    procs: list[subprocess.Popen] = []
    gateway_procs = 0  # procs[0] the emulator, then one link per port (--driver gateway)
    coordinators: list[subprocess.Popen] = []  # the coordinator and its standby, stopped first
    ros2_procs: list[subprocess.Popen] = []  # simulated ROS 2 robots and the bridge, stopped after the agents
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
            hub_session = stack.enter_context(open_session(hub_settings))
            stack.enter_context(published_run(run_id, hub, f"swarm {o.command}"))
            stack.callback(stop_children)  # before the hub closes
            lifeline.guard(Path(tmp))
            _acks_sub, acks = subscribe_queue(hub_session, estop_ack_key(run_id))

            def stop_run(reason: str) -> str:
                """The run-wide stop, waiting (at most ``ESTOP_ACK_S``) until every agent acknowledged it."""
                stop = EmergencyStop(run=run_id, step=0, source=f"swarm {o.command} (pid {os.getpid()})", reason=reason)
                sent = publish_estop(hub_session, stop)
                heard = sum(by == "agent" for by, _ in collect_acks(acks, stop.stamp_ns, sent[0] + ESTOP_ACK_S, traj.n))
                return f"emergency stop sent to run {run_id} (acknowledged by {heard} of {traj.n} agents)"

            traj_file = Path(tmp) / "trajectory.json"
            traj.save(traj_file)
            model = flags(o.model_flags)
            agent_extra = list(model)
            if o.driver not in BUILT_IN:
                agent_extra += [f"--driver={plugin_spec(o.driver)}", *(f"--driver-option={x}" for x in o.driver_options)]
                if o.command_timeout is not None:
                    agent_extra.append(f"--command-timeout={o.command_timeout!r}")
            world_flags = [f"--physics-speed={o.physics_speed!r}", *(f"--physics-param={x}" for x in o.physics_params)]
            if o.world == "physics" and o.driver == "sim":  # the agent process steps the world
                agent_extra += ["--world=physics", *world_flags]
            emulator_extra = ["--physics", *world_flags] if o.world == "physics" else []  # the robot emulator steps it
            truth = o.driver in BUILT_IN or driver_class(o.driver).simulated
            step_timeout = DEFAULT_STEP_TIMEOUT_S if o.step_timeout is None else o.step_timeout
            if o.driver == "ros2":
                ros2_options, truth = ros2_settings(o)
                if o.step_timeout is None:
                    step_timeout = ros2_step_timeout(ros2_options)
                if not truth:
                    say(f"swarm {o.command}: the ROS 2 robots' settings name no ground truth (--driver-option ground_truth=TOPIC, "
                        f"e.g. ground_truth of swarm ros2 robots): the run has no true poses, so no P_f and no contacts")
                agent_extra += ["--driver=ros2", *(f"--driver-option={x}" for x in ros2_options)]
                if o.ros2_robots:  # the same settings: namespaces, frame, topics
                    ros2_procs.append(subprocess.Popen(
                        [py, "-m", "swarm_cli.ros2", "robots", f"--trajectory={traj_file}", f"--seed={o.seed}", *model,
                         *(f"--driver-option={x}" for x in ros2_options)], **tied))
            if o.ros2:
                ros2_procs.append(subprocess.Popen(
                    [py, "-m", "swarm_cli.ros2", "bridge", f"--run={run_id}", f"--hub={hub}", f"--trajectory={traj_file}",
                     f"--robot-radius={o.model.robot_radius_m!r}"], **tied))
            if o.driver == "gateway":
                gateway = GatewayConfig.load(o.gateway_config) if o.gateway_config else default_gateway(traj, robot_radius=o.model.robot_radius_m)
                missing = sorted(set(int(i) for i in traj.ids) - set(gateway.robots))
                if missing:
                    raise SwarmInputError(f"robots {missing} of the trajectory are behind no port of the gateway config")
                live = start_gateway(traj_file, gateway, Path(tmp), run_id, hub, o.seed, o.motion_time, model, procs,
                                     o.emulator_events, [*faults, *emulator_extra], links=not port_hosts, **tied)
                gateway_procs = len(procs)
                agent_extra += ["--driver=gateway", f"--gateway-config={live}"]
            first = len(procs)
            piped = {**tied, **agent_errors.popen_kwargs()}
            try:
                if port_hosts:  # one process per port: its link and its robots' agents
                    agent_procs = start_port_hosts(traj, live, run_id, hub, o.seed, o.motion_time, agent_extra, procs, traj_file, **piped)
                else:
                    start_agents(traj, run_id, hub, o.seed, o.motion_time, agent_extra, procs, per_process, traj_file, **piped)
                    agent_procs = {int(robot): procs[first + k // per_process] for k, robot in enumerate(traj.ids)}  # its hosting process
            finally:
                agent_errors.watch(procs[first:])
            agent_list = procs[first:]
            common = [f"--run={run_id}", f"--hub={hub}", f"--seed={o.seed}", *model]
            if not truth:
                common.append("--no-truth")  # the lab's robots publish no true poses
            cmd = [py, "-m", "swarm_cli.coordinator_cmd", f"--trajectory={traj_file}", f"--method={o.method}",
                   f"--step-timeout={step_timeout!r}", f"--out={out}", *common, *flags(o.coordinator_flags),
                   f"--start-timeout={max(30.0, START_S_PER_ROBOT * traj.n)!r}"]
            if o.result:
                cmd.append(f"--result={o.result}")
            recording = None if o.no_record else (o.record or default_recording(run_id))
            cmd.append("--no-record" if recording is None else f"--record={recording}")
            if o.json:
                cmd.append("--json")
            if o.foxglove is not None:
                cmd.append(f"--foxglove={o.foxglove}")
                if o.linger is not None:
                    cmd.append(f"--linger={o.linger!r}")
            what = {"sim": "agents", "gateway": "gateway agents + emulated robots",
                    "ros2": "ROS 2 agents" + (" + simulated ROS 2 robots" if o.ros2_robots else "")}.get(o.driver, f"agents ({o.driver})")
            what += " in the physical world" if o.world == "physics" else ""
            hosts = "" if per_process == 1 and not port_hosts else f" in {len(set(map(id, agent_procs.values())))} processes"
            say(f"swarm {o.command}: {traj.n} {what}{hosts} + coordinator, run {run_id}, hub {hub} "
                f"(emergency stop: swarm estop --run {run_id})")
            killed: dict[int, int] = {}  # pid -> when it was killed: robots hosted by one process die together
            killers = [RobotKiller(hub_session, run_id, robot, step, agent_procs[robot], killed) for robot, step in o.kills]
            stallers: dict[str, ProcessStaller] = {}
            if o.stall_link is not None:
                first_port = GatewayConfig.load(live).ports[0]
                link_proc = agent_procs[first_port.robots[0]] if port_hosts else procs[1]
                stallers["link_stall"] = ProcessStaller(hub_session, run_id, *o.stall_link, link_proc)
            json_hold = o.json and (bool(killers) or o.kill_coordinator is not None or bool(stallers) or
                                    o.stall_coordinator is not None)
            standby = None
            if o.standby:
                standby_record = [a for a in cmd if not a.startswith("--record=")] + (
                    [] if recording is None else [f"--record={Path(recording).with_suffix('.standby.mcap')}"])
                standby = subprocess.Popen([*standby_record, "--standby"], stdout=subprocess.PIPE if json_hold else None, text=True, **tied)
                coordinators.append(standby)
                procs.append(standby)
                wait_for_standby(hub_session, run_id, standby)
            coordinator = subprocess.Popen(cmd, stdout=subprocess.PIPE if json_hold else None, text=True, **tied)
            coordinators.insert(0, coordinator)  # before its standby (which then sees the run stopped)
            procs.append(coordinator)
            coord_killer = None if o.kill_coordinator is None else CoordinatorKiller(hub_session, run_id, o.kill_coordinator, coordinator)
            if o.stall_coordinator is not None:
                stallers["coordinator_stall"] = ProcessStaller(hub_session, run_id, *o.stall_coordinator, coordinator)
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
                    say(f"swarm {o.command}: the coordinator was killed (signal {-status}); the standby takes over")
                    status = standby.wait()
                elif standby is not None and status == EXIT_STEPPED_DOWN:  # it stalled past its lease: the standby holds the run
                    say(f"swarm {o.command}: the coordinator stepped down (another coordinator holds the run); waiting for the standby")
                    status = standby.wait()
            except KeyboardInterrupt:
                say(f"swarm {o.command}: interrupted: {stop_run('the launcher was interrupted')}")
                raise
            if status not in (0, EXIT_OUTPUT):  # an abort, an error or a killed coordinator: stop every robot
                done = stop_run(f"the coordinator exited with status {status}")
                say(f"swarm {o.command}: the coordinator exited with status {status}: {done}")
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
                say(f"swarm {o.command}: killed the agent of robot {kill['robot']} at step {kill['step']}; its emergency "
                    f"stop was sent {kill['detect_ms']} ms and heard {kill['estop_ms']} ms after the kill")
            coord_kill = None if coord_killer is None else coord_killer.report()
            if coord_kill is not None:
                say(f"swarm {o.command}: killed the coordinator at step {coord_kill['step']}; the next coordinator's first "
                    f"command came {coord_kill['takeover_ms']} ms after the kill")
            stalls = {name: staller.report() for name, staller in stallers.items()}
            for name, stall in stalls.items():
                if stall is not None:
                    say(f"swarm {o.command}: stalled the {name.split('_')[0]} (SIGSTOP) at step {stall['step']} for {stall['stall_s']} s")
            if json_hold:
                summary = {}
                for line in last:  # the last line of each coordinator: the one that finished the run is a JSON object
                    try:
                        summary = json.loads(line)
                    except json.JSONDecodeError:  # a coordinator that failed before its JSON line: pass it on as it was
                        sys.stdout.write(line)
                extra = {} if not killers else {"kill": kills[0], "kills": kills}
                if coord_killer is not None:
                    extra["coordinator_kill"] = coord_kill
                extra.update(stalls)
                emit_json({**summary, **extra})
            if recording is not None and Path(recording).exists():
                say(f"swarm {o.command}: recording {recording}" if is_finished(recording) else
                    f"swarm {o.command}: recording {recording} is incomplete: the recording failed (what reached the disk: "
                    f"swarm info {recording}; swarm recover {recording})")
            return status if status >= 0 else 128 - status  # killed by signal N: 128 + N, as a shell reports it
    finally:
        stop_children()
        for line in agent_errors.held():  # an agent's error that did not end the start: as it printed it
            say(line)
        lifeline.close()
        signals.restore()
