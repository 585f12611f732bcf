"""``swarm launch`` and ``swarm demo``: a whole distributed run on this host.

The launcher opens the run's Zenoh router hub itself on a free loopback port, writes
the trajectory to a temporary file if it generated it, starts one ``swarm agent``
process per robot (initial true pose from the trajectory), then ``swarm coordinator``,
and waits for the coordinator, whose summary appears on stdout; the coordinator writes
the Fig. 13/14/17 plots to ``--out`` (default ``out/demo`` or ``out/launch``) and prints
their paths. The coordinator records the run to ``recordings/<run>.mcap`` (``--record PATH``
to choose, ``--no-record`` to turn it off) and prints the path; the launcher repeats it on
stderr at the end. On exit, error or
Ctrl-C it stops every child it started by its pid (SIGTERM, then SIGKILL after a grace
period), so no process outlives it. Exit status: the coordinator's.

``swarm demo`` is ``swarm launch`` with 10 agents on a built-in small trajectory
(``random_trajectory(10, 3, seed 0)``).

``--driver gateway`` runs the hardware path end to end without hardware: the launcher
starts ``swarm emulate-robots`` (robots speaking the frame protocol on ptys, true poses
in the emulator, which publishes them like a motion-capture system), one ``swarm link``
per port of the gateway config (``--gateway-config``, default: ports of 5 robots each),
and the agents with the gateway driver; the coordinator and its command line are the
same as with ``--driver sim``. Ctrl-C (or SIGTERM) first publishes an ``EmergencyStop``
to the run, then stops every child.

``agent_command``, ``start_agents`` and ``stop_all`` are the reusable pieces (also used by
``swarm bench runtime``).
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from coordinator.strategies import METHODS
from runtime.errors import SwarmInputError
from runtime.gateway_config import GatewayConfig, Limits, Port
from runtime.messages import CommandLimits
from runtime.trajectory import Trajectory, random_trajectory
from runtime.transport import free_tcp_port, loopback_hub, open_session
from swarm_cli.coordinator_cmd import add_record_options, default_recording
from swarm_cli.emulate import check_radio_faults
from swarm_cli.estop import send_estop
from swarm_cli.options import add_simulation_options, model_config

GRACE_S = 3.0
MODEL_OPTIONS = ("turn_sigma_deg", "drive_sigma_frac", "range_sigma", "bearing_sigma_deg", "sensing_range", "dropout")
COORD_OPTIONS = ("localizer", "w_v", "samples", "population", "generations")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("launch", help="run agents + coordinator as processes on this host (Zenoh on loopback)")
    p.add_argument("-n", "--robots", type=int, default=10, help="robots of the random trajectory (default 10)")
    p.add_argument("--trajectory", type=Path, help="trajectory JSON (docs/trajectory.md); default: a random one")
    p.add_argument("--configs", type=int, default=3, help="configurations of the random trajectory (default 3)")
    add_run_options(p)
    p.set_defaults(run=run)
    d = sub.add_parser("demo", help="a distributed run of 10 agent processes on a small built-in trajectory")
    add_run_options(d)
    d.set_defaults(run=run_demo, trajectory=None, robots=10, configs=3)


def add_run_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--method", choices=METHODS, default="inchworm", help="motion strategy (default inchworm)")
    p.add_argument("--seed", type=int, default=0, help="seed of the noise, initial estimate and search (default 0)")
    p.add_argument("--run", dest="run_id", default=None, help="run id (default launch-<pid>)")
    p.add_argument("--result", type=Path, help="the coordinator writes every step's estimate to this JSON file")
    p.add_argument("--out", type=Path, default=None, help="folder for the plots (default out/demo, or out/launch for swarm launch)")
    p.add_argument("--motion-time", type=float, default=0.0, help="seconds a simulated motion takes (default 0)")
    p.add_argument("--step-timeout", type=float, default=5.0, help="seconds the coordinator waits for a step's answers (default 5)")
    p.add_argument("--driver", choices=("sim", "gateway"), default="sim",
                   help="simulated agents, or agents driving emulated robots through link processes and ptys (default sim)")
    p.add_argument("--gateway-config", type=Path, default=None,
                   help="with --driver gateway: the gateway config to emulate (default: ports of 5 robots each)")
    p.add_argument("--emulator-events", type=Path, default=None, help="with --driver gateway: the emulator's JSON-lines event log")
    p.add_argument("--drop", type=float, default=0.0, metavar="P", help="with --driver gateway: probability the emulated radio loses a frame, each way (default 0)")
    p.add_argument("--corrupt", type=float, default=0.0, metavar="P", help="with --driver gateway: probability a robot's answer has a byte flipped (default 0)")
    p.add_argument("--delay", type=float, default=0.0, metavar="S", help="with --driver gateway: seconds every answer of the robots is delayed (default 0)")
    add_record_options(p)
    add_simulation_options(p)


def run_demo(args: argparse.Namespace) -> int:
    return run(args)


def _forward(args: argparse.Namespace, names: tuple[str, ...]) -> list[str]:
    """``--name=value`` for each option (``=`` so negative numbers pass; repr so floats are exact)."""
    return [f"--{name.replace('_', '-')}={getattr(args, name)!r}".replace("'", "") for name in names]


def agent_command(
    robot: int, ids: str, pose, run_id: str, hub: str, seed: int, motion_time: float = 0.0, extra: list[str] | tuple[str, ...] = ()
) -> list[str]:
    """The command line of robot ``robot``'s agent process (``ids`` comma-separated, ``pose`` x, y, heading)."""
    return [sys.executable, "-m", "swarm_cli.agent", f"--id={int(robot)}", f"--ids={ids}",
            f"--pose={','.join(repr(float(v)) for v in pose)}", f"--motion-time={float(motion_time)!r}",
            f"--run={run_id}", f"--hub={hub}", f"--seed={seed}", *extra]


def start_agents(
    traj: Trajectory, run_id: str, hub: str, seed: int, motion_time: float = 0.0, extra: list[str] | tuple[str, ...] = (),
    procs: list[subprocess.Popen] | None = None, **popen_kwargs,
) -> list[subprocess.Popen]:
    """One agent process per robot of ``traj`` (initial true pose from it), appended to ``procs`` as each starts.

    Pass your own ``procs`` list so that the ones already started can be stopped if a later start fails.
    """
    procs = [] if procs is None else procs
    ids = ",".join(str(int(i)) for i in traj.ids)
    for robot, pose in zip(traj.ids, traj.initial_poses):
        procs.append(subprocess.Popen(agent_command(int(robot), ids, pose, run_id, hub, seed, motion_time, extra), **popen_kwargs))
    return procs


def stop_all(procs: list[subprocess.Popen], grace_s: float = GRACE_S) -> None:
    """SIGTERM every child still running, SIGKILL those still running after ``grace_s``; reap all."""
    for p in procs:
        if p.poll() is None:
            try:
                p.send_signal(signal.SIGTERM)
            except ProcessLookupError:
                pass
    deadline = time.monotonic() + grace_s
    for p in procs:
        try:
            p.wait(timeout=max(0.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


def _raise_interrupt(*_) -> None:
    raise KeyboardInterrupt


ROBOTS_PER_PORT = 5
GATEWAY_READY_S = 20.0


def default_gateway(traj: Trajectory, margin_m: float = 1.0) -> GatewayConfig:
    """Ports ``radio0``, ``radio1``, ... of ``ROBOTS_PER_PORT`` robots each; the workspace is the
    trajectory's bounding box grown by ``margin_m``; devices are filled in by the emulator."""
    ids = [int(i) for i in traj.ids]
    ports = tuple(Port(f"radio{k}", "emulated", tuple(ids[i:i + ROBOTS_PER_PORT]))
                  for k, i in enumerate(range(0, len(ids), ROBOTS_PER_PORT)))
    xy = np.concatenate([traj.initial_poses[:, :2], *traj.configurations])
    lo, hi = xy.min(axis=0) - margin_m, xy.max(axis=0) + margin_m
    return GatewayConfig(ports, limits=Limits(max_drive_m=CommandLimits().max_drive_m, workspace=(lo[0], lo[1], hi[0], hi[1])))


def start_emulator(config: Path, traj_file: Path, live: Path, options: list[str], procs: list[subprocess.Popen]) -> Path:
    """Start ``swarm emulate-robots`` for the gateway config ``config`` (appended to ``procs``) and wait
    until it wrote ``live``, the same config with its pty devices; returns ``live``."""
    emulator = subprocess.Popen([sys.executable, "-m", "swarm_cli.emulate", f"--config={config}", f"--trajectory={traj_file}",
                                 f"--write-config={live}", *options], stdout=subprocess.DEVNULL)
    procs.append(emulator)
    deadline = time.monotonic() + GATEWAY_READY_S
    while not live.exists():
        if emulator.poll() is not None:
            raise SwarmInputError(f"the robot emulator exited with status {emulator.returncode} before its ptys were ready")
        if time.monotonic() > deadline:
            raise SwarmInputError(f"the robot emulator did not write {live} within {GATEWAY_READY_S:.0f} s")
        time.sleep(0.02)
    return live


def radio_faults(drop: float, corrupt: float, delay: float) -> list[str]:
    """The emulator options of the radio faults ``--drop P --corrupt P --delay S``, checked (errors name the flag)."""
    check_radio_faults(drop, corrupt, delay)
    return [f"--drop={drop!r}", f"--corrupt={corrupt!r}", f"--delay={delay!r}"]


def start_gateway(traj_file: Path, gateway: GatewayConfig, tmp: Path, run_id: str, hub: str, seed: int, motion_time: float,
                  model: list[str], procs: list[subprocess.Popen], events: Path | None = None,
                  faults: list[str] | tuple[str, ...] = ()) -> Path:
    """Start the robot emulators (with the ``radio_faults`` options ``faults``) and one link process per port;
    the live gateway config (pty devices)."""
    config = tmp / "gateway.json"
    gateway.save(config)
    options = [f"--seed={seed}", f"--motion-time={motion_time!r}", f"--hub={hub}", f"--run={run_id}", *model, *faults]
    if events is not None:
        options.append(f"--events={events}")
    live = start_emulator(config, traj_file, tmp / "gateway-live.json", options, procs)
    for port in gateway.ports:
        procs.append(subprocess.Popen([sys.executable, "-m", "swarm_cli.link", f"--config={live}", f"--port={port.name}",
                                       f"--run={run_id}", f"--hub={hub}"]))
    return live


def run(args: argparse.Namespace) -> int:
    cfg = model_config(args)
    faults = radio_faults(args.drop, args.corrupt, args.delay)
    if args.driver != "gateway" and (args.drop or args.corrupt or args.delay):
        raise SwarmInputError("--drop, --corrupt and --delay are faults of the emulated radio: they need --driver gateway")
    if args.trajectory:
        traj = Trajectory.load(args.trajectory)
    else:
        if args.robots < 2 or args.configs < 1:
            raise SwarmInputError("a launched swarm needs -n >= 2 robots and --configs >= 1")
        seed = 0 if args.command == "demo" else args.seed
        traj = random_trajectory(args.robots, args.configs, np.random.default_rng(seed), sensing_range=cfg.sensing_range_m)
    run_id = args.run_id or f"launch-{os.getpid()}"
    port = free_tcp_port()
    hub_settings, _ = loopback_hub(port)
    hub = f"tcp/127.0.0.1:{port}"
    out = args.out or Path("out") / args.command
    py = sys.executable
    procs: list[subprocess.Popen] = []
    previous = signal.signal(signal.SIGTERM, _raise_interrupt)
    try:
        with tempfile.TemporaryDirectory(prefix="swarm-launch-") as tmp, open_session(hub_settings) as hub_session:
            traj_file = Path(tmp) / "trajectory.json"
            traj.save(traj_file)
            model = _forward(args, MODEL_OPTIONS)
            agent_extra = list(model)
            if args.driver == "gateway":
                gateway = GatewayConfig.load(args.gateway_config) if args.gateway_config else default_gateway(traj)
                missing = sorted(set(int(i) for i in traj.ids) - set(gateway.robots))
                if missing:
                    raise SwarmInputError(f"robots {missing} of the trajectory are behind no port of the gateway config")
                live = start_gateway(traj_file, gateway, Path(tmp), run_id, hub, args.seed, args.motion_time, model, procs,
                                     args.emulator_events, faults)
                agent_extra += ["--driver=gateway", f"--gateway-config={live}"]
            start_agents(traj, run_id, hub, args.seed, args.motion_time, agent_extra, procs)
            common = [f"--run={run_id}", f"--hub={hub}", f"--seed={args.seed}", *model]
            cmd = [py, "-m", "swarm_cli.coordinator_cmd", f"--trajectory={traj_file}", f"--method={args.method}",
                   f"--step-timeout={args.step_timeout!r}", f"--out={out}", *common, *_forward(args, COORD_OPTIONS)]
            if args.result:
                cmd.append(f"--result={args.result}")
            recording = None if args.no_record else (args.record or default_recording(run_id))
            cmd.append("--no-record" if recording is None else f"--record={recording}")
            if args.json:
                cmd.append("--json")
            if args.foxglove is not None:
                cmd.append(f"--foxglove={args.foxglove}")
            what = "agents" if args.driver == "sim" else "gateway agents + emulated robots"
            print(f"swarm {args.command}: {traj.n} {what} + coordinator, run {run_id}, hub {hub}", file=sys.stderr, flush=True)
            coordinator = subprocess.Popen(cmd)
            procs.append(coordinator)
            try:
                status = coordinator.wait()
            except KeyboardInterrupt:
                send_estop(hub_session, run_id, f"swarm {args.command} (pid {os.getpid()})", "Ctrl-C of the launcher")
                print(f"swarm {args.command}: interrupted: emergency stop sent to run {run_id}", file=sys.stderr, flush=True)
                raise
            if recording is not None and Path(recording).exists():
                print(f"swarm {args.command}: recording {recording}", file=sys.stderr, flush=True)
            return status
    finally:
        emulators = 1 if args.driver == "gateway" else 0  # stopped last, after the links that read their ptys
        stop_all(procs[emulators:])
        stop_all(procs[:emulators])
        signal.signal(signal.SIGTERM, previous)
