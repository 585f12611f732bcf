"""``swarm launch`` and ``swarm demo``: a whole distributed run on this host (``inchworm.launcher``: what it
starts, checks and stops, and the fault injection of ``--kill-robot ID@STEP``, ``--standby``,
``--kill-coordinator STEP``, ``--stall-coordinator STEP:SECONDS`` and ``--stall-link STEP:SECONDS``). While it
runs, ``swarm estop --run RUN`` and ``swarm record --run RUN`` find its hub (its run file); a run id already
live on this host is refused. Exit status: the coordinator's (128 + N if it was killed by signal N; the standby's
when the coordinator stepped down); with ``--json`` and a kill or stall, the last line is the coordinator's JSON
object with ``"kill"`` / ``"coordinator_kill"`` / ``"coordinator_stall"`` / ``"link_stall"`` added.

``swarm demo`` is ``swarm launch`` with 10 agents on a built-in small trajectory
(``random_trajectory(10, 3, seed 0)``) in a scenario where the online selection chooses
anchors (``DEMO_SCENARIO``: the joint localizer and 4x the default motion noise; measured in
docs/quickstart.md); ``--paper`` keeps the paper's localizer and the default noise, where it
chooses none unless moving every robot at once would bring bodies together (``PAPER_TEXT``). Options given
explicitly override either.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path

from inchworm.launch_options import DriverOptions, FaultOptions, OutputOptions, SwarmOptions
from inchworm.processes import AGENTS_PER_PROCESS, ONE_PER_PROCESS_UP_TO
from inchworm.specs import LaunchSpec
from swarm_cli.coordinator_cmd import add_record_options
from swarm_cli.options import add_simulation_options, add_world_options, model_config, nonnegative, positive, selection_spec_of
from swarm_cli.schema import add_fields

DEMO_SCENARIO = {"localizer": "joint", "turn_sigma_deg": 12.0, "drive_sigma_frac": 0.2}  # 4x the default motion noise
PAPER_SCENARIO = {"localizer": "paper"}  # and the noise every other command defaults to (ModelConfig, or --model FILE)
DEMO_TEXT = ("demo scenario: joint localizer, motion noise 4x the default (turn 12 deg, drive 20 %): a robot that stands "
             "still keeps its estimate, so the others localize against it far better than when everybody moves; the "
             "selection weighs that against the extra step and chooses anchors (--paper: the paper's localizer and noise)")

PAPER_TEXT = ("the paper's localizer (Section 5) and the default noise: anchors barely improve its estimate, so the "
              "selection chooses speed, n_a = 0, wherever moving every robot at once keeps the bodies apart; where it "
              "does not, the best-scoring anchor count with a plan that does (the tables below say which)")


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("launch", help="run agents + coordinator as processes on this host (Zenoh on loopback)")
    for name in ("robots", "trajectory", "configs"):
        add_fields(p, SwarmOptions, only=(name,))
    add_run_options(p)
    p.set_defaults(run=run)
    d = sub.add_parser("demo", help="a distributed run of 10 agent processes on a small built-in trajectory",
                       description=f"A distributed run of 10 agent processes on a small built-in trajectory. {DEMO_TEXT}")
    d.add_argument("--paper", action="store_true",
                   help="the paper's localizer (Section 5) and the default noise instead of the demo scenario")
    add_run_options(d)
    d.set_defaults(run=run_demo, trajectory=None, robots=10, configs=3, **{name: None for name in DEMO_SCENARIO})


def add_run_options(p: argparse.ArgumentParser) -> None:
    """The flags of ``swarm launch`` and ``swarm demo`` after the trajectory's: most declared by the fields of
    ``inchworm.launch_options`` (``swarm_cli.schema``), those whose command-line form differs (a repeated flag, yes/no,
    ``ID@STEP``, ``STEP:SECONDS``) here."""
    for name in ("method", "seed", "run_id"):
        add_fields(p, SwarmOptions, only=(name,))
    for name in ("result", "out"):
        add_fields(p, OutputOptions, only=(name,))
    add_fields(p, SwarmOptions, only=("motion_time",), types={"motion_time": nonnegative})
    add_fields(p, SwarmOptions, only=("step_timeout",), types={"step_timeout": positive})
    p.add_argument("--driver", default="sim", metavar="DRIVER",
                   help="sim: simulated agents (default); gateway: agents driving emulated robots through link processes and ptys; "
                        "ros2: robots speaking ROS 2 (cmd_vel, odom, neighbors; docs/ros2.md); "
                        "or a lab's own driver package.module:Class, file.py:Class or entry point name (docs/drivers.md)")
    p.add_argument("--driver-option", action="append", default=[], metavar="KEY=VALUE",
                   help="with a lab's own driver or ros2 (config=FILE, settings; docs/ros2.md): an option passed to every agent's "
                        "driver, repeatable")
    add_fields(p, DriverOptions, only=("command_timeout",), types={"command_timeout": positive})
    for name in ("gateway_config", "emulator_events"):
        add_fields(p, DriverOptions, only=(name,))
    for name in ("on_lost", "min_robots"):
        add_fields(p, SwarmOptions, only=(name,))
    p.add_argument("--rejoin", choices=("yes", "no"), default="yes",
                   help="a lost robot whose agent comes back rejoins at the next configuration (default yes)")
    p.add_argument("--kill-robot", type=_kill_spec, action="append", default=None, metavar="ID@STEP",
                   help="fault injection: SIGKILL the agent of robot ID when global step STEP starts (e.g. 3@2); repeatable")
    for name in ("standby", "kill_coordinator"):
        add_fields(p, FaultOptions, only=(name,))
    p.add_argument("--stall-coordinator", type=_stall_spec, default=None, metavar="STEP:SECONDS",
                   help="fault injection: SIGSTOP the coordinator when global step STEP starts and SIGCONT it SECONDS later "
                        "(e.g. 2:12; beyond the 10 s Zenoh lease a --standby takes the run over and the stalled one steps down)")
    p.add_argument("--stall-link", type=_stall_spec, default=None, metavar="STEP:SECONDS",
                   help="fault injection with --driver gateway: SIGSTOP the process of the first port's link when global step "
                        "STEP starts and SIGCONT it SECONDS later (e.g. 2:3: its robots' watchdogs stop them)")
    p.add_argument("--agents-per-process", type=int, default=None,
                   help=f"robot agents hosted by one process (default 1 up to {ONE_PER_PROCESS_UP_TO} robots, else up to "
                        f"{AGENTS_PER_PROCESS}; gateway: one process per port with its link, given: link processes apart; ros2: up to "
                        f"{AGENTS_PER_PROCESS} in one, unless --kill-robot)")
    add_fields(p, FaultOptions, only=("drop", "corrupt", "delay"))
    add_fields(p, OutputOptions, only=("ros2",))
    add_fields(p, DriverOptions, only=("ros2_robots",))
    add_record_options(p)
    add_simulation_options(p)
    add_world_options(p, speed=True)


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


def _stall_spec(text: str) -> tuple[int, float]:
    """``STEP:SECONDS`` -> (step >= 1, seconds > 0)."""
    step, sep, seconds = text.partition(":")
    try:
        if not sep:
            raise ValueError
        step_no, secs = int(step), float(seconds)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not STEP:SECONDS (e.g. 2:12)") from None
    if step_no < 1 or not 0 < secs < 3600:
        raise argparse.ArgumentTypeError(f"{text!r}: the step must be >= 1 and the seconds between 0 and 3600")
    return step_no, secs


def run_demo(args: argparse.Namespace) -> int:
    """``swarm launch`` on the demo scenario (or with ``--paper`` the paper's defaults); explicit options win."""
    scenario = PAPER_SCENARIO if args.paper else DEMO_SCENARIO
    if args.model is not None:  # a model file gives the noise: the scenario only picks the localizer
        scenario = {"localizer": scenario["localizer"]}
    given = [name for name in DEMO_SCENARIO if getattr(args, name) is not None]
    for name, value in scenario.items():
        if getattr(args, name) is None:
            setattr(args, name, value)
    what = PAPER_TEXT if args.paper else DEMO_TEXT
    over = [f"--{n.replace('_', '-')}" for n in given] + ([f"--model {args.model}"] if args.model is not None else [])
    print(f"swarm demo: {what}" + (f" (overridden: {', '.join(over)})" if over else ""), flush=True)
    return run(args)


def spec_of(args: argparse.Namespace) -> LaunchSpec:
    """The launch spec of the options."""
    text: Callable[[Path | None], str | None] = lambda path: None if path is None else str(path)  # noqa: E731
    return LaunchSpec(
        model=model_config(args), model_file=text(args.model), localizer=args.localizer, selection=selection_spec_of(args),
        command=args.command, trajectory=text(args.trajectory), robots=args.robots, configs=args.configs,
        trajectory_seed=0 if args.command == "demo" else args.seed, method=args.method, seed=args.seed, run_id=args.run_id,
        out=text(args.out), result=text(args.result), motion_time=args.motion_time, step_timeout=args.step_timeout, driver=args.driver,
        driver_options=tuple(args.driver_option), command_timeout=args.command_timeout, gateway_config=text(args.gateway_config),
        emulator_events=text(args.emulator_events), min_robots=args.min_robots, kill_robot=tuple(args.kill_robot or ()),
        standby=args.standby, kill_coordinator=args.kill_coordinator, agents_per_process=args.agents_per_process, drop=args.drop,
        corrupt=args.corrupt, delay=args.delay, record=text(args.record), no_record=args.no_record, foxglove=args.foxglove,
        linger=args.linger, json=args.json, on_lost=args.on_lost, rejoin=args.rejoin == "yes", on_record_error=args.on_record_error,
        world=args.world, physics_params=tuple(args.physics_param), physics_speed=args.physics_speed, ros2=args.ros2,
        ros2_robots=args.ros2_robots, stall_coordinator=args.stall_coordinator, stall_link=args.stall_link)


def run(args: argparse.Namespace) -> int:
    from inchworm.process_mains import run_launch  # noqa: PLC0415 - zenoh and scipy only when launching

    return run_launch(spec_of(args))
