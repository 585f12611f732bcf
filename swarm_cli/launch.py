"""``swarm launch`` and ``swarm demo``: a whole distributed run on this host.

The launcher opens the run's Zenoh router hub itself on a free loopback port, writes
the trajectory to a temporary file if it generated it, starts one ``swarm agent``
process per robot (initial true pose from the trajectory), or with ``--agents-per-process K``
one per K robots (default: one per robot up to ``ONE_PER_PROCESS_UP_TO`` robots, larger
swarms in processes of at most ``AGENTS_PER_PROCESS``), then ``swarm coordinator``,
and waits for the coordinator, whose summary appears on stdout; the coordinator writes
the Fig. 13/14/17 plots to ``--out`` (default ``out/demo`` or ``out/launch``) and prints
their paths. The coordinator records the run to ``recordings/<run>.mcap`` (``--record PATH``
to choose, ``--no-record`` to turn it off) and prints the path; the launcher repeats it on
stderr at the end. On exit, error or
Ctrl-C it stops every child it started by its pid (SIGTERM, then SIGKILL after a grace
period), so no process outlives it. Exit status: the coordinator's. While it runs it keeps the
run file ``<run dir>/<run>.json`` with the hub's address (``swarm_cli.run_file``; removed at exit),
so ``swarm estop --run RUN`` and ``swarm record --run RUN`` need no ``--hub``; a run id that is
already live on this host is refused.

``swarm demo`` is ``swarm launch`` with 10 agents on a built-in small trajectory
(``random_trajectory(10, 3, seed 0)``) in a scenario where the online selection chooses
anchors (``DEMO_SCENARIO``: the joint localizer and 4x the default motion noise; measured in
docs/quickstart.md); ``--paper`` keeps the paper's localizer and the default noise, where it
chooses none. Options given explicitly override either.

``--driver gateway`` runs the hardware path end to end without hardware: the launcher
starts ``swarm emulate-robots`` (robots speaking the frame protocol on ptys, true poses
in the emulator, which publishes them like a motion-capture system), one ``swarm link``
per port of the gateway config (``--gateway-config``, default: ports of 5 robots each),
and the agents with the gateway driver; the coordinator and its command line are the
same as with ``--driver sim``. Ctrl-C (or SIGTERM, SIGHUP; each child also stops itself if the launcher is
killed: ``swarm_cli.lifeline``) first publishes an ``EmergencyStop`` (waiting for every agent's acknowledgement)
to the run, then stops every child; so does a coordinator that ends with an error or is
killed (any exit status but 0), so no robot is left moving.

``--driver package.module:Class`` (or ``file.py:Class``, an entry point name) starts the agents with a
lab's own driver (docs/drivers.md), given ``--driver-option``s and ``--command-timeout``; a driver
that is not ``simulated`` gets a coordinator with ``--no-truth``.

``--kill-robot ID@STEP`` SIGKILLs the agent process of robot ID (with several agents per
process: the process hosting it, and so its other robots too) as soon as the
coordinator sends the first command of global step STEP (fault injection for demos,
tests and ``swarm bench faults``); the launcher then times the coordinator's reaction
(its targeted ``EmergencyStop``: detection = its stamp, arrival = when the launcher
heard it) and prints it; with ``--json`` the last line is the coordinator's JSON object
with a ``"kill"`` entry added: ``{"robot", "step", "detect_ms", "estop_ms"}``.

``inchworm.processes`` holds the reusable pieces (``agent_command``, ``start_agents``, ``stop_all``) (also used by
``swarm bench runtime``).

``--standby`` also starts a standby coordinator (``swarm coordinator --standby``, same options,
recording to ``<record>.standby.mcap``): if the coordinator dies without a word (SIGKILL, OOM)
the standby takes the run over from its last checkpoint, the launcher sends no emergency stop
and waits for the standby, whose summary and exit status become the launcher's.
``--kill-coordinator STEP`` SIGKILLs the coordinator at the first command of global step STEP
(fault injection); the launcher times the takeover: from the kill to the first command or
observation request of the new coordinator's epoch, and with ``--json`` adds
``"coordinator_kill": {"step", "takeover_ms"}`` to the last line.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import socket
import subprocess
import sys
import tempfile
import threading
from pathlib import Path

import numpy as np

from coordinator.process import EXIT_OUTPUT, default_recording
from coordinator.stop import StopSignals, collect_acks, publish_estop
from coordinator.strategies import METHODS
from inchworm.processes import (
    AGENTS_PER_PROCESS,
    GRACE_S,
    ONE_PER_PROCESS_UP_TO,
    CoordinatorKiller,
    RobotKiller,
    agents_per_process,
    default_gateway,
    radio_faults,
    start_agents,
    start_gateway,
    stop_all,
    wait_for_standby,
)
from robot_agent.assembly import driver_options
from robot_agent.plugins import BUILT_IN, driver_class
from runtime.errors import SwarmInputError
from runtime.gateway.config import GatewayConfig
from runtime.models.bodies import validate_passable
from runtime.models.trajectory import Trajectory, body_spacing, random_trajectory, validate_connected
from runtime.wire.keys import estop_ack_key, validate_run
from runtime.wire.messages import EmergencyStop
from runtime.wire.transport import free_tcp_port, loopback_hub, open_session, subscribe_queue
from swarm_cli.coordinator_cmd import add_record_options
from swarm_cli.lifeline import Lifeline
from swarm_cli.options import add_simulation_options, check_swarm_size, model_config, nonnegative, positive, print_json, selection_config
from swarm_cli.run_file import published_run

COORDINATOR_GRACE_S = 20.0  # s the coordinator gets to finish its recording after SIGTERM
MODEL_OPTIONS = ("model", "turn_sigma_deg", "drive_sigma_frac", "range_sigma", "bearing_sigma_deg", "sensing_range", "dropout", "robot_radius")
COORD_OPTIONS = ("localizer", "w_v", "samples", "population", "generations", "mc_start", "mc_emax", "on_lost", "min_robots", "rejoin",
                 "on_record_error")
ESTOP_ACK_S = 2.0  # s the launcher waits for every agent to acknowledge its run-wide stop before it stops them
DEMO_SCENARIO = {"localizer": "joint", "turn_sigma_deg": 12.0, "drive_sigma_frac": 0.2}  # 4x the default motion noise
PAPER_SCENARIO = {"localizer": "paper"}  # and the noise every other command defaults to (ModelConfig, or --model FILE)
DEMO_TEXT = ("demo scenario: joint localizer, motion noise 4x the default (turn 12 deg, drive 20 %): a robot that stands "
             "still keeps its estimate, so the others localize against it far better than when everybody moves; the "
             "selection weighs that against the extra step and chooses anchors (--paper: the paper's localizer and noise)")
START_S_PER_ROBOT = 0.1  # the coordinator waits this long per robot (at least 30 s) for every agent: 500 took 22-30 s on a busy 2-core machine


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("launch", help="run agents + coordinator as processes on this host (Zenoh on loopback)")
    p.add_argument("-n", "--robots", type=int, default=10, help="robots of the random trajectory (default 10)")
    p.add_argument("--trajectory", type=Path, help="trajectory JSON (docs/trajectory.md); default: a random one")
    p.add_argument("--configs", type=int, default=3, help="configurations of the random trajectory (default 3)")
    add_run_options(p)
    p.set_defaults(run=run)
    d = sub.add_parser("demo", help="a distributed run of 10 agent processes on a small built-in trajectory",
                       description=f"A distributed run of 10 agent processes on a small built-in trajectory. {DEMO_TEXT}")
    d.add_argument("--paper", action="store_true",
                   help="the paper's localizer (Section 5) and the default noise instead of the demo scenario")
    add_run_options(d)
    d.set_defaults(run=run_demo, trajectory=None, robots=10, configs=3, **{name: None for name in DEMO_SCENARIO})


def add_run_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--method", choices=METHODS, default="inchworm", help="motion strategy (default inchworm)")
    p.add_argument("--seed", type=int, default=0, help="seed of the noise, initial estimate and search (default 0)")
    p.add_argument("--run", dest="run_id", default=None, help="run id (default launch-<pid>)")
    p.add_argument("--result", type=Path, help="the coordinator writes every step's estimate to this JSON file")
    p.add_argument("--out", type=Path, default=None, help="folder for the plots (default out/demo, or out/launch for swarm launch)")
    p.add_argument("--motion-time", type=nonnegative, default=0.0, help="seconds a simulated motion takes (default 0)")
    p.add_argument("--step-timeout", type=positive, default=5.0, help="seconds the coordinator waits for a step's answers (default 5)")
    p.add_argument("--driver", default="sim", metavar="DRIVER",
                   help="sim: simulated agents (default); gateway: agents driving emulated robots through link processes and ptys; "
                        "or a lab's own driver package.module:Class, file.py:Class or entry point name (docs/drivers.md)")
    p.add_argument("--driver-option", action="append", default=[], metavar="KEY=VALUE",
                   help="with a lab's own driver: an option passed to every agent's driver, repeatable")
    p.add_argument("--command-timeout", type=positive, default=None, metavar="S",
                   help="with a lab's own driver: seconds each command or observation may take before the agent stops the "
                        "robot and reports it lost (default: swarm agent's)")
    p.add_argument("--gateway-config", type=Path, default=None,
                   help="with --driver gateway: the gateway config to emulate (default: ports of 5 robots each)")
    p.add_argument("--emulator-events", type=Path, default=None, help="with --driver gateway: the emulator's JSON-lines event log")
    p.add_argument("--on-lost", choices=("continue", "abort"), default="continue",
                   help="when a robot is lost: stop it and go on without it, or end the run (default continue)")
    p.add_argument("--min-robots", type=int, default=2, help="end the run when fewer robots are left (default 2)")
    p.add_argument("--rejoin", choices=("yes", "no"), default="yes",
                   help="a lost robot whose agent comes back rejoins at the next configuration (default yes)")
    p.add_argument("--kill-robot", type=_kill_spec, default=None, metavar="ID@STEP",
                   help="fault injection: SIGKILL the agent of robot ID when global step STEP starts (e.g. 3@2)")
    p.add_argument("--standby", action="store_true",
                   help="also start a standby coordinator that takes the run over if the coordinator dies")
    p.add_argument("--kill-coordinator", type=int, default=None, metavar="STEP",
                   help="fault injection: SIGKILL the coordinator when global step STEP starts (with --standby: time the takeover)")
    p.add_argument("--agents-per-process", type=int, default=None,
                   help=f"robot agents hosted by one process (default 1 up to {ONE_PER_PROCESS_UP_TO} robots, "
                        f"else up to {AGENTS_PER_PROCESS} per process)")
    p.add_argument("--drop", type=float, default=0.0, metavar="P",
                   help="with --driver gateway: probability the emulated radio loses a frame, each way (default 0)")
    p.add_argument("--corrupt", type=float, default=0.0, metavar="P",
                   help="with --driver gateway: probability a robot's answer has a byte flipped (default 0)")
    p.add_argument("--delay", type=float, default=0.0, metavar="S",
                   help="with --driver gateway: seconds every answer of the robots is delayed (default 0)")
    add_record_options(p)
    add_simulation_options(p)


def _kill_spec(text: str) -> tuple[int, int]:
    """``ID@STEP`` -> (robot id, step >= 1)."""
    robot, sep, step = text.partition("@")
    try:
        if not sep:
            raise ValueError
        robot_id, step_no = int(robot), int(step)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not ID@STEP (e.g. 3@2)") from None
    if robot_id < 0 or step_no < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: the robot id must be >= 0 and the step >= 1")
    return robot_id, step_no


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


def run_demo(args: argparse.Namespace) -> int:
    """``swarm launch`` on the demo scenario (or with ``--paper`` the paper's defaults); explicit options win."""
    scenario = PAPER_SCENARIO if args.paper else DEMO_SCENARIO
    if args.model is not None:  # a model file gives the noise: the scenario only picks the localizer
        scenario = {"localizer": scenario["localizer"]}
    given = [name for name in DEMO_SCENARIO if getattr(args, name) is not None]
    for name, value in scenario.items():
        if getattr(args, name) is None:
            setattr(args, name, value)
    what = ("the paper's localizer (Section 5) and the default noise: anchors barely improve its estimate, so the "
            "selection chooses speed (n_a = 0)") if args.paper else DEMO_TEXT
    over = [f"--{n.replace('_', '-')}" for n in given] + ([f"--model {args.model}"] if args.model is not None else [])
    print(f"swarm demo: {what}" + (f" (overridden: {', '.join(over)})" if over else ""), flush=True)
    return run(args)


def _forward(args: argparse.Namespace, names: tuple[str, ...]) -> list[str]:
    """``--name=value`` for each option given (``=`` so negative numbers pass; repr so floats are exact)."""
    return [f"--{name.replace('_', '-')}={_arg_text(getattr(args, name))}" for name in names if getattr(args, name) is not None]


def _arg_text(value) -> str:
    return str(value) if isinstance(value, (str, Path)) else repr(value)


def plugin_spec(spec: str) -> str:
    """``--driver`` as the agents get it: a ``file.py:Class`` path made absolute (they may start elsewhere)."""
    module, sep, attr = spec.rpartition(":")
    return f"{Path(module).resolve()}:{attr}" if sep and module.endswith(".py") else spec


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


def check_before_start(args: argparse.Namespace, traj: Trajectory, cfg, run_id: str, out: Path) -> None:
    """Everything that can fail before a process is started: the run id, the trajectory, the strategy
    options, the recording, plot and result folders, the Foxglove extra and port; each error names the flag."""
    from coordinator.localization import make_localizer  # noqa: PLC0415 - scipy, only when launching
    from coordinator.strategies import make_strategy  # noqa: PLC0415
    from runtime.recording.foxglove_live import require_foxglove  # noqa: PLC0415

    try:
        validate_run(run_id)
    except SwarmInputError as exc:
        raise SwarmInputError(f"--run {run_id!r}: {exc}") from None
    validate_connected(traj, cfg.sensing_range_m)
    validate_passable(traj, cfg)
    make_strategy(args.method, traj.n, cfg, make_localizer(args.localizer, cfg), selection_config(args), args.seed)
    if not args.no_record:
        record = Path(args.record or default_recording(run_id))
        _check_writable(record.parent, "--record", record)
    _check_writable(out, "--out", out)
    if args.result:
        _check_writable(Path(args.result).parent, "--result", args.result)
    if args.foxglove is not None:
        require_foxglove()
        with socket.socket() as probe:
            try:
                probe.bind(("127.0.0.1", args.foxglove))
            except OSError as exc:
                raise SwarmInputError(f"--foxglove {args.foxglove}: cannot serve on 127.0.0.1:{args.foxglove}: {exc.strerror or exc}") from None
    if args.driver == "gateway" and args.gateway_config:
        radius = GatewayConfig.load(args.gateway_config).limits.robot_radius_m
        if radius != cfg.robot_radius_m:
            raise SwarmInputError(f"--robot-radius {cfg.robot_radius_m:g} differs from the robots' body radius {radius:g} m "
                                  f"in {args.gateway_config} (limits.robot_radius_m): plan with the robots' own bodies")
    if args.driver not in BUILT_IN:
        driver_class(args.driver)
        driver_options(args.driver_option)
    if args.kill_coordinator is not None and args.kill_coordinator < 1:
        raise SwarmInputError(f"--kill-coordinator {args.kill_coordinator}: the step must be >= 1")
    if args.kill_robot is not None and args.kill_robot[0] not in traj.ids:
        robot, step = args.kill_robot
        raise SwarmInputError(f"--kill-robot {robot}@{step}: robot {robot} is not one of the run's robots {traj.ids.tolist()}")


def run(args: argparse.Namespace) -> int:
    cfg = model_config(args)
    faults = radio_faults(args.drop, args.corrupt, args.delay)
    if args.driver != "gateway" and (args.drop or args.corrupt or args.delay):
        raise SwarmInputError("--drop, --corrupt and --delay are faults of the emulated radio: they need --driver gateway")
    if args.trajectory:
        traj = Trajectory.load(args.trajectory)
        check_swarm_size(traj.n, f"--trajectory {args.trajectory}", launched=True)
    else:
        if args.robots < 2 or args.configs < 1:
            raise SwarmInputError("a launched swarm needs -n >= 2 robots and --configs >= 1")
        seed = 0 if args.command == "demo" else args.seed
        traj = random_trajectory(args.robots, args.configs, np.random.default_rng(seed), sensing_range=cfg.sensing_range_m, **body_spacing(cfg))
    if not 2 <= args.min_robots <= traj.n:
        raise SwarmInputError(f"--min-robots {args.min_robots}: must be between 2 and the {traj.n} robots of the run")
    per_process = agents_per_process(traj.n, args.agents_per_process)
    run_id = args.run_id or f"launch-{os.getpid()}"
    out = args.out or Path("out") / args.command
    check_before_start(args, traj, cfg, run_id, out)
    port = free_tcp_port()
    hub_settings, _ = loopback_hub(port)
    hub = f"tcp/127.0.0.1:{port}"
    py = sys.executable
    procs: list[subprocess.Popen] = []
    gateway_procs = 0  # procs[0] the emulator, then one link per port (--driver gateway)
    coordinators: list[subprocess.Popen] = []  # the coordinator and its standby, stopped first
    signals = StopSignals()  # Ctrl-C / SIGTERM / SIGHUP: estop, then every child stopped; never interrupts the stopping
    lifeline = Lifeline()  # every child ends with this process, even after SIGKILL
    tied = lifeline.child_options()

    def stop_children() -> None:
        """Coordinator, agents, links, emulator: in this order, while the hub still routes (called twice: idempotent)."""
        with signals.deferred():
            if coordinators:  # first, with time to finish their recordings
                stop_all(coordinators, COORDINATOR_GRACE_S)
            stop_all(procs[gateway_procs:])  # the agents, before the links they talk through (no "link gone" at the end)
            stop_all(procs[1:gateway_procs])  # the links, before the emulator whose ptys they read
            stop_all(procs[:1] if gateway_procs else [])

    try:
        with contextlib.ExitStack() as stack:
            tmp = stack.enter_context(tempfile.TemporaryDirectory(prefix="swarm-launch-"))
            hub_session = stack.enter_context(open_session(hub_settings))
            stack.enter_context(published_run(run_id, hub, f"swarm {args.command}"))
            stack.callback(stop_children)  # before the hub closes
            lifeline.guard(Path(tmp))
            _acks_sub, acks = subscribe_queue(hub_session, estop_ack_key(run_id))

            def stop_run(reason: str) -> str:
                """The run-wide stop, waiting (at most ``ESTOP_ACK_S``) until every agent acknowledged it."""
                stop = EmergencyStop(run=run_id, step=0, source=f"swarm {args.command} (pid {os.getpid()})", reason=reason)
                sent = publish_estop(hub_session, stop)
                heard = sum(by == "agent" for by, _ in collect_acks(acks, stop.stamp_ns, sent[0] + ESTOP_ACK_S, traj.n))
                return f"emergency stop sent to run {run_id} (acknowledged by {heard} of {traj.n} agents)"

            traj_file = Path(tmp) / "trajectory.json"
            traj.save(traj_file)
            model = _forward(args, MODEL_OPTIONS)
            agent_extra = list(model)
            if args.driver not in BUILT_IN:
                agent_extra += [f"--driver={plugin_spec(args.driver)}", *(f"--driver-option={o}" for o in args.driver_option)]
                if args.command_timeout is not None:
                    agent_extra.append(f"--command-timeout={args.command_timeout!r}")
            if args.driver == "gateway":
                gateway = GatewayConfig.load(args.gateway_config) if args.gateway_config else default_gateway(traj, robot_radius=cfg.robot_radius_m)
                missing = sorted(set(int(i) for i in traj.ids) - set(gateway.robots))
                if missing:
                    raise SwarmInputError(f"robots {missing} of the trajectory are behind no port of the gateway config")
                live = start_gateway(traj_file, gateway, Path(tmp), run_id, hub, args.seed, args.motion_time, model, procs,
                                     args.emulator_events, faults, **tied)
                gateway_procs = len(procs)
                agent_extra += ["--driver=gateway", f"--gateway-config={live}"]
            first = len(procs)
            start_agents(traj, run_id, hub, args.seed, args.motion_time, agent_extra, procs, per_process, traj_file, **tied)
            agent_procs = {int(robot): procs[first + k // per_process] for k, robot in enumerate(traj.ids)}  # its hosting process
            common = [f"--run={run_id}", f"--hub={hub}", f"--seed={args.seed}", *model]
            if args.driver not in BUILT_IN and not driver_class(args.driver).simulated:
                common.append("--no-truth")  # the lab's robots publish no true poses
            cmd = [py, "-m", "swarm_cli.coordinator_cmd", f"--trajectory={traj_file}", f"--method={args.method}",
                   f"--step-timeout={args.step_timeout!r}", f"--out={out}", *common, *_forward(args, COORD_OPTIONS),
                   f"--start-timeout={max(30.0, START_S_PER_ROBOT * traj.n)!r}"]
            if args.result:
                cmd.append(f"--result={args.result}")
            recording = None if args.no_record else (args.record or default_recording(run_id))
            cmd.append("--no-record" if recording is None else f"--record={recording}")
            if args.json:
                cmd.append("--json")
            if args.foxglove is not None:
                cmd.append(f"--foxglove={args.foxglove}")
                if args.linger is not None:
                    cmd.append(f"--linger={args.linger!r}")
            what = {"sim": "agents", "gateway": "gateway agents + emulated robots"}.get(args.driver, f"agents ({args.driver})")
            hosts = "" if per_process == 1 else f" in {-(-traj.n // per_process)} processes"
            print(f"swarm {args.command}: {traj.n} {what}{hosts} + coordinator, run {run_id}, hub {hub} "
                  f"(emergency stop: swarm estop --run {run_id})", file=sys.stderr, flush=True)
            killer = None
            if args.kill_robot is not None:
                robot, step = args.kill_robot
                killer = RobotKiller(hub_session, run_id, robot, step, agent_procs[robot])
            json_hold = args.json and (killer is not None or args.kill_coordinator is not None)
            standby = None
            if args.standby:
                standby_record = [a for a in cmd if not a.startswith("--record=")] + (
                    [] if recording is None else [f"--record={Path(recording).with_suffix('.standby.mcap')}"])
                standby = subprocess.Popen([*standby_record, "--standby"], stdout=subprocess.PIPE if json_hold else None, text=True, **tied)
                procs.append(standby)
                coordinators.append(standby)
                wait_for_standby(hub_session, run_id, standby)
            coordinator = subprocess.Popen(cmd, stdout=subprocess.PIPE if json_hold else None, text=True, **tied)
            procs.append(coordinator)
            coordinators.insert(0, coordinator)  # before its standby (which then sees the run stopped)
            coord_killer = None if args.kill_coordinator is None else CoordinatorKiller(hub_session, run_id, args.kill_coordinator, coordinator)
            last: list[str] = []
            forwarders = [threading.Thread(target=_forward_output, args=(p.stdout, last), daemon=True)
                          for p in (coordinator, standby) if json_hold and p is not None]
            for forwarder in forwarders:
                forwarder.start()
            try:
                status = coordinator.wait()
                if standby is not None and status < 0:  # died without a word: the standby takes the run over
                    print(f"swarm {args.command}: the coordinator was killed (signal {-status}); the standby takes over",
                          file=sys.stderr, flush=True)
                    status = standby.wait()
            except KeyboardInterrupt:
                print(f"swarm {args.command}: interrupted: {stop_run('the launcher was interrupted')}", file=sys.stderr, flush=True)
                raise
            if status not in (0, EXIT_OUTPUT):  # an abort, an error or a killed coordinator: stop every robot
                done = stop_run(f"the coordinator exited with status {status}")
                print(f"swarm {args.command}: the coordinator exited with status {status}: {done}", file=sys.stderr, flush=True)
            if standby is not None:
                try:
                    standby.wait(timeout=GRACE_S)  # it saw the run finish (or stop) and exits by itself
                except subprocess.TimeoutExpired:
                    stop_all([standby], COORDINATOR_GRACE_S)
            for forwarder in forwarders:
                forwarder.join(timeout=10)
            kill = None if killer is None else killer.report()
            if kill is not None:
                print(f"swarm {args.command}: killed the agent of robot {kill['robot']} at step {kill['step']}; its emergency "
                      f"stop was sent {kill['detect_ms']} ms and heard {kill['estop_ms']} ms after the kill", file=sys.stderr, flush=True)
            coord_kill = None if coord_killer is None else coord_killer.report()
            if coord_kill is not None:
                print(f"swarm {args.command}: killed the coordinator at step {coord_kill['step']}; the next coordinator's first "
                      f"command came {coord_kill['takeover_ms']} ms after the kill", file=sys.stderr, flush=True)
            if json_hold:
                summary = {}
                for line in last:  # the last line of each coordinator: the one that finished the run is a JSON object
                    try:
                        summary = json.loads(line)
                    except json.JSONDecodeError:  # a coordinator that failed before its JSON line: pass it on as it was
                        sys.stdout.write(line)
                extra = {} if killer is None else {"kill": kill}
                if coord_killer is not None:
                    extra["coordinator_kill"] = coord_kill
                print_json({**summary, **extra})
            if recording is not None and Path(recording).exists():
                print(f"swarm {args.command}: recording {recording}", file=sys.stderr, flush=True)
            return status if status >= 0 else 128 - status  # killed by signal N: 128 + N, as a shell reports it
    finally:
        stop_children()
        lifeline.close()
        signals.restore()
