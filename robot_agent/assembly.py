"""The agents of one agent process (``swarm agent``): which robots it hosts, and the driver of each.

``--id`` / ``--ids`` texts name robots (``0-49``, ``0,2,5-9``); ``build_agents`` makes one
``Agent`` per hosted robot with its driver: simulated (``sim``, from its initial true pose),
a robot behind a gateway link (``gateway``: limits and calibration from the gateway config,
docs/gateway.md), a robot speaking ROS 2 (``ros2``, docs/ros2.md), or a lab's own driver class
(docs/drivers.md); ``build_links`` the links this process runs itself (``--link``). Errors name the flag.
"""

from __future__ import annotations

import re
from collections.abc import Iterable
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from robot_agent.agent import READY_TIMEOUT_S, Agent
from robot_agent.driver import Driver, DriverContext, SimDriver
from robot_agent.gateway_driver import GatewayDriver
from robot_agent.host import LinkFactory
from robot_agent.plugins import BUILT_IN, build_driver, driver_class
from runtime.errors import OptionError, SwarmInputError
from runtime.gateway.config import GatewayConfig
from runtime.models.config import ModelConfig
from runtime.wire.messages import CommandLimits

if TYPE_CHECKING:
    from runtime.models.trajectory import Trajectory
    from runtime.wire.transport import ZenohSettings
    from runtime.world.params import PhysicsParams

PLUGIN_COMMAND_TIMEOUT_S = 30.0


def parse_ids(text: str, option: str) -> list[int]:
    """Robot ids of an option such as ``--id 0-49`` or ``--ids 0,2,5-9`` (ranges inclusive), in the order given."""
    ids: list[int] = []
    for part in (p.strip() for p in str(text).split(",")):
        match = re.fullmatch(r"(\d+)(?:-(\d+))?", part)
        if match is None or (match[2] is not None and int(match[2]) < int(match[1])):
            raise SwarmInputError(f"{option} must be robot ids >= 0 and ranges a-b with a <= b, comma-separated (e.g. 0-49), got {text!r}")
        ids.extend(range(int(match[1]), int(match[2] or match[1]) + 1))
    if len(set(ids)) != len(ids):
        raise SwarmInputError(f"{option} names a robot twice: {text!r}")
    return ids


def format_ids(ids: Iterable[int]) -> str:
    """The shortest ``parse_ids`` text of ``ids`` (runs of consecutive ids as ranges): [0, 1, 2, 5] -> ``0-2,5``."""
    parts: list[list[int]] = []  # [first, last] of each run
    for i in ids:
        i = int(i)
        if parts and parts[-1][1] == i - 1:
            parts[-1][1] = i
        else:
            parts.append([i, i])
    return ",".join(str(a) if a == b else f"{a}-{b}" for a, b in parts)


def driver_options(pairs: list[str]) -> dict[str, str]:
    """``--driver-option KEY=VALUE`` pairs as a dict (a key given twice: the last value)."""
    out = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or not key.strip():
            raise OptionError("driver_option", f"must be KEY=VALUE, got {pair!r}")
        out[key.strip()] = value
    return out


@dataclass(frozen=True)
class AgentSpec:
    """The agents of one process: ``hosted`` robots of the run's ``ids`` and how to drive them (SI units)."""

    settings: ZenohSettings
    run_id: str
    hosted: list[int] = field(metadata={"flag": "--id"})
    ids: list[int] | None  # None: the robots of ``trajectory``
    ids_text: str | None = None  # ``--ids`` as given, for messages
    trajectory: Trajectory | None = None
    trajectory_path: Path | None = None
    pose: list[float] | None = None  # one simulated robot's initial true pose (x, y, heading)
    driver: str = "sim"
    options: dict[str, str] = field(default_factory=dict)  # a lab's driver's options
    gateway_config: Path | None = None
    seed: int = 0
    model: ModelConfig = field(default_factory=ModelConfig)
    motion_time_s: float = 0.0
    limits: CommandLimits = field(default_factory=CommandLimits)
    ready_timeout_s: float = READY_TIMEOUT_S
    command_timeout_s: float | None = None  # None: a lab's driver gets PLUGIN_COMMAND_TIMEOUT_S, the others none
    link: bool = False  # also run the link of the hosted robots' port(s) in this process (``build_links``)
    physics: PhysicsParams | None = None  # the physical world (``--world physics``), else the noise model's
    physics_speed: float = 0.0  # world seconds per wall second (0: as fast as it computes)


def make_driver(spec: AgentSpec, robot: int, ids: list[int], pose: np.ndarray | list[float] | None = None, gateway: GatewayConfig | None = None,
                plugin: type[Driver] | None = None) -> tuple[Driver, CommandLimits]:
    """The driver and limits of ``robot`` (``pose``: its initial true pose, if known; ``plugin``: a lab's driver class)."""
    if spec.driver == "gateway":
        if gateway is None:
            if spec.gateway_config is None:
                raise OptionError("driver", "gateway needs `gateway_config` FILE (docs/gateway.md)", spec)
            gateway = GatewayConfig.load(spec.gateway_config)
        port = gateway.port_of(robot)  # the robot must be behind a port of this gateway
        lim = gateway.limits
        limits = CommandLimits(max_drive_m=lim.max_drive_m, max_turn_rad=lim.max_turn_rad, workspace=lim.workspace)
        return GatewayDriver(spec.run_id, robot, gateway.calibration_of(robot), gateway.timing, port.name), limits
    if pose is None:
        pose = spec.pose
    if spec.driver != "sim":
        if spec.driver == "ros2":
            from robot_agent.ros2_driver import Ros2Driver  # noqa: PLC0415 - rclpy only for ROS 2 robots

            cls: type[Driver] = Ros2Driver
        else:
            cls = plugin or driver_class(spec.driver)
        context = DriverContext(robot=int(robot), ids=tuple(int(i) for i in ids), run=spec.run_id, seed=spec.seed,
                                pose=None if pose is None else np.array(pose, dtype=float), model=spec.model, options=spec.options)
        return build_driver(spec.driver, cls, context), spec.limits
    if pose is None:
        raise OptionError("driver", "sim needs `pose` x,y,heading (the simulated robot's initial true pose) or `trajectory` FILE", spec)
    return SimDriver(robot, ids, pose, spec.model, spec.seed, spec.motion_time_s), spec.limits


def build_links(spec: AgentSpec, ids: list[int]) -> dict[str, LinkFactory]:
    """With ``spec.link`` (``--link``): the link of every port behind which a hosted robot is (port name -> its factory), to run on the host's
    session (``AgentHost``). Each such port's robots that are in the run (``ids``) must all be hosted here: a port has
    one link, and its robots' requests reach it inside this process only."""
    if not spec.link:
        return {}
    if spec.driver != "gateway" or spec.gateway_config is None:
        raise OptionError("link", "runs the link of a port of the gateway: it needs `driver` gateway and `gateway_config` FILE", spec)
    from robot_agent.link import Link  # noqa: PLC0415 - keeps the link off the import path of agents that run none

    gateway = GatewayConfig.load(spec.gateway_config)
    ports = {gateway.port_of(r).name: gateway.port_of(r) for r in spec.hosted}
    for port in ports.values():
        elsewhere = sorted(set(port.robots) & set(ids) - set(spec.hosted))
        if elsewhere:
            raise OptionError("link", f": robots {elsewhere} of port {port.name} are robots of the run but not hosted by this process "
                                      f"(`hosted` {format_ids(spec.hosted)}): host every robot of the port, or run `swarm link` for it", spec)
    return {name: partial(Link.open, run=spec.run_id, port=port, config=gateway) for name, port in ports.items()}


def build_agents(spec: AgentSpec) -> list[Agent]:
    """One ``Agent`` per hosted robot, each with its own driver; everything checked before any is made."""
    plugin = None if spec.driver in BUILT_IN else driver_class(spec.driver)
    traj, hosted = spec.trajectory, spec.hosted
    if spec.ids is not None:
        ids = spec.ids
    elif traj is not None:
        ids = [int(i) for i in traj.ids]
    else:
        raise OptionError("ids", "(every robot of the run, e.g. 0-9) or `trajectory` FILE must be given", spec)
    outside = sorted(set(hosted) - set(ids))
    if outside:
        raise OptionError("hosted", f"names robots {outside} that are not robots of the run (`ids` {spec.ids_text or format_ids(ids)})", spec)
    poses: dict[int, np.ndarray] = {}
    if spec.driver != "gateway" and spec.pose is None and traj is not None:
        missing = sorted(set(hosted) - {int(i) for i in traj.ids})
        if missing and spec.driver == "sim":
            raise OptionError("hosted", f"names robots {missing} that {spec.trajectory_path} does not have", spec)
        poses = {int(i): p for i, p in zip(traj.ids, traj.initial_poses, strict=True)}
    elif len(hosted) > 1 and (spec.driver == "sim" or (spec.driver != "gateway" and spec.pose is not None)):
        raise OptionError("pose", f"is one robot's pose: give `trajectory` FILE for the initial poses of `hosted` {format_ids(hosted)}", spec)
    gateway = None
    if spec.driver == "gateway":
        if spec.gateway_config is None:
            raise OptionError("driver", "gateway needs `gateway_config` FILE (docs/gateway.md)", spec)
        gateway = GatewayConfig.load(spec.gateway_config)
    timeout = spec.command_timeout_s if spec.command_timeout_s is not None or plugin is None else PLUGIN_COMMAND_TIMEOUT_S
    if spec.physics is not None:
        return _physics_agents(spec, ids, poses, timeout)
    return [Agent(spec.settings, spec.run_id, robot, ids, *make_driver(spec, robot, ids, poses.get(robot), gateway, plugin),
                  spec.ready_timeout_s, timeout) for robot in hosted]


def _physics_agents(spec: AgentSpec, ids: list[int], poses: dict[int, np.ndarray], timeout: float | None) -> list[Agent]:
    """``--world physics``: every robot of the run in one world, hosted by this process (docs/physics.md)."""
    from robot_agent.physics_driver import PhysicsDriver, SharedWorld  # noqa: PLC0415 - the physics extra, only when asked for
    from runtime.world.physics import World  # noqa: PLC0415

    if spec.driver != "sim":
        raise OptionError("world", f"physics drives simulated robots: it needs `driver` sim, got `driver` {spec.driver}", spec)
    if sorted(spec.hosted) != sorted(ids):
        raise OptionError("world", f"physics steps one world for every robot of the run: host them all in this process "
                                   f"(`hosted` {format_ids(sorted(ids))}), got `hosted` {format_ids(spec.hosted)}", spec)
    missing = sorted(set(ids) - set(poses))
    if missing:
        raise OptionError("world", f"physics needs every robot's initial pose from `trajectory` FILE; robots {missing} have none", spec)
    assert spec.physics is not None
    world = World(ids, np.array([poses[r] for r in ids], dtype=float), spec.physics, spec.seed)
    shared = SharedWorld(world, spec.run_id, spec.physics_speed)
    return [Agent(spec.settings, spec.run_id, robot, ids, PhysicsDriver(robot, shared), spec.limits, spec.ready_timeout_s, timeout)
            for robot in spec.hosted]
