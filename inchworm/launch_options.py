"""The options of a whole distributed run (``inchworm.launcher.launch``, ``inchworm.Swarm``, ``swarm launch``), by
concern: ``SwarmOptions``, ``DriverOptions``, ``FaultOptions``, ``OutputOptions`` and ``LaunchOptions`` holding
them. Checked when made (``OptionError`` naming the field). A module of their own, light to import: ``swarm
launch`` builds its parser from these declarations (``swarm_cli.schema``) without loading Zenoh.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from coordinator.localization.registry import DEFAULT_LOCALIZER
from coordinator.strategies import METHODS
from inchworm.limits import check_option_limits
from inchworm.options import check_at_least, default_selection
from runtime.errors import OptionError
from runtime.models.config import ModelConfig
from runtime.paths import StrPath, coerce_paths

if TYPE_CHECKING:
    from coordinator.selection.selector import SelectionConfig

ON_LOST = ("continue", "abort")  # what a run does when a robot is lost


@dataclass(frozen=True, kw_only=True)
class SwarmOptions:
    """What runs: the trajectory (a file, else a random one of ``robots`` x ``configs`` drawn with ``trajectory_seed``),
    the method and its ``seed``, the noise model, localizer and anchor selection (checked before anything starts),
    the run id (default ``launch-<pid>``), the lost-robot policy and the world. Times in seconds. They go to the
    processes in their specs (``inchworm.specs``; ``model_file``: the file ``model`` was read from, for the
    recording's metadata)."""

    trajectory: StrPath | None = field(default=None, metadata={"help": "trajectory JSON (docs/trajectory.md); default: a random one"})
    robots: int = field(default=10, metadata={"flag": "-n", "help": "robots of the random trajectory"})
    configs: int = field(default=3, metadata={"help": "configurations of the random trajectory"})
    trajectory_seed: int = 0
    method: str = field(default="inchworm", metadata={"help": "motion strategy", "choices": METHODS})
    seed: int = field(default=0, metadata={"help": "seed of the noise, initial estimate and search"})
    model: ModelConfig = field(default_factory=ModelConfig)
    model_file: StrPath | None = None
    localizer: str = DEFAULT_LOCALIZER
    selection: SelectionConfig = field(default_factory=default_selection)
    run_id: str | None = field(default=None, metadata={"flag": "--run", "help": "run id (default launch-<pid>)"})
    min_robots: int = field(default=2, metadata={"help": "end the run when fewer robots are left"})
    on_lost: str = field(default="continue", metadata={  # "abort": end the run when a robot is lost
        "help": "when a robot is lost: stop it and go on without it, or end the run", "choices": ON_LOST})
    rejoin: bool = True  # a lost robot whose agent comes back rejoins at the next configuration
    motion_time: float = field(default=0.0, metadata={"help": "seconds a simulated motion takes"})
    step_timeout: float | None = field(default=None, metadata={  # None: DEFAULT_STEP_TIMEOUT_S, driver "ros2": ``ros2_step_timeout``
        "help": "seconds the coordinator waits for a step's answers (default 5; --driver ros2: the slowest motion its speeds allow, "
                "x 1.5, + 2 s)"})
    agents_per_process: int | None = None
    world: str = "model"  # or "physics": the simulated agents (all in one process) or ROS 2 robots drive in the rigid-body world (docs/physics.md)
    physics_params: tuple[str, ...] = field(default=(), metadata={"flag": "--physics-param"})  # NAME=VALUE
    physics_speed: float = 0.0

    def __post_init__(self) -> None:
        coerce_paths(self, "trajectory", "model_file")
        if self.on_lost not in ON_LOST:
            raise OptionError("on_lost", f"must be 'continue' or 'abort', got {self.on_lost!r}", self)
        if self.world not in ("model", "physics"):
            raise OptionError("world", f"must be 'model' or 'physics', got {self.world!r}", self)
        if not self.trajectory:
            check_at_least(self, "robots", 2)
            check_at_least(self, "configs", 1)
        check_at_least(self, "min_robots", 2)
        check_at_least(self, "motion_time", 0.0)
        check_option_limits(self, launched=True)


@dataclass(frozen=True, kw_only=True)
class DriverOptions:
    """What drives the robots: ``name`` ``sim`` (simulated agents), ``gateway`` (emulated robots behind link processes;
    ``gateway_config``, ``emulator_events``), ``ros2`` (``ros2_robots``: simulated ROS 2 robots started first) or a lab's
    own driver (``package.module:Class``, ``file.py:Class``, an entry point name) with its ``options`` (KEY=VALUE) and
    ``command_timeout`` (s)."""

    name: str = field(default="sim", metadata={"flag": "--driver"})
    options: tuple[str, ...] = field(default=(), metadata={"flag": "--driver-option"})
    command_timeout: float | None = field(default=None, metadata={"metavar": "S", "help": (
        "with a lab's own driver: seconds each command or observation may take before the agent stops the robot and reports it "
        "lost (default: swarm agent's)")})
    gateway_config: StrPath | None = field(default=None, metadata={
        "help": "with --driver gateway: the gateway config to emulate (default: ports of 5 robots each)"})
    emulator_events: StrPath | None = field(default=None, metadata={"help": "with --driver gateway: the emulator's JSON-lines event log"})
    ros2_robots: bool = field(default=False, metadata={
        "help": "with --driver ros2: also start simulated ROS 2 robots of the trajectory (swarm ros2 robots) to drive"})

    def __post_init__(self) -> None:
        coerce_paths(self, "gateway_config", "emulator_events")


@dataclass(frozen=True, kw_only=True)
class FaultOptions:
    """Fault injection (module doc): ``kill_robot`` one ``(ID, STEP)`` or several, ``standby`` and ``kill_coordinator``
    (STEP), ``stall_coordinator`` / ``stall_link`` (STEP, SECONDS), and the emulated radio's ``drop`` / ``corrupt``
    probabilities and ``delay`` (s; driver ``gateway``)."""

    kill_robot: tuple[int, int] | tuple[tuple[int, int], ...] | None = None
    standby: bool = field(default=False, metadata={"help": "also start a standby coordinator that takes the run over if the coordinator dies"})
    kill_coordinator: int | None = field(default=None, metadata={"metavar": "STEP", "help": (
        "fault injection: SIGKILL the coordinator when global step STEP starts (with --standby: time the takeover)")})
    stall_coordinator: tuple[int, float] | None = None
    stall_link: tuple[int, float] | None = None
    drop: float = field(default=0.0, metadata={
        "metavar": "P", "help": "with --driver gateway: probability the emulated radio loses a frame, each way"})
    corrupt: float = field(default=0.0, metadata={"metavar": "P", "help": "with --driver gateway: probability a robot's answer has a byte flipped"})
    delay: float = field(default=0.0, metadata={"metavar": "S", "help": "with --driver gateway: seconds every answer of the robots is delayed"})

    def __post_init__(self) -> None:
        if self.kill_coordinator is not None:
            check_at_least(self, "kill_coordinator", 1)
        for name in ("stall_coordinator", "stall_link"):
            stall = getattr(self, name)
            if stall is not None and (stall[0] < 1 or not stall[1] > 0):
                raise OptionError(name, f"{stall[0]}:{stall[1]:g}: the step must be >= 1 and the seconds > 0", self)
        for robot, step in self.kills:
            if robot < 0 or step < 1:
                raise OptionError("kill_robot", f"{robot}@{step}: the robot id must be >= 0 and the step >= 1", self)

    @property
    def kills(self) -> list[tuple[int, int]]:
        """Every ``(robot, step)`` of ``kill_robot``."""
        spec = self.kill_robot
        if not spec:
            return []
        if isinstance(spec[0], int):
            return [(int(spec[0]), int(spec[1]))]
        return [(int(robot), int(step)) for robot, step in spec]


@dataclass(frozen=True, kw_only=True)
class OutputOptions:
    """What the run leaves: plots in ``out`` (default ``out/<command>``), every step's estimate in ``result``, the
    recording (``record``, default ``recordings/<run>.mcap``; ``no_record``; ``on_record_error``), the live views
    (``foxglove`` port and ``linger`` s, ``ros2``: the ROS 2 bridge) and, with ``json``, the JSON object on stdout.
    ``command`` is how the launcher names itself (``launch`` / ``demo``)."""

    command: str = "launch"
    out: StrPath | None = field(default=None, metadata={"help": "folder for the plots (default out/demo, or out/launch for swarm launch)"})
    result: StrPath | None = field(default=None, metadata={"help": "the coordinator writes every step's estimate to this JSON file"})
    record: StrPath | None = None
    no_record: bool = False
    on_record_error: str = "continue"  # or "stop"
    foxglove: int | None = None
    linger: float | None = None
    ros2: bool = field(default=False, metadata={"help": (
        "show the run live in ROS 2: /swarm/estimates, /swarm/robot<id>/pose, /swarm/markers, service /swarm/estop "
        "(swarm ros2 bridge; extra ros2, docs/ros2.md)")})
    json: bool = False

    def __post_init__(self) -> None:
        coerce_paths(self, "out", "result", "record")


@dataclass(frozen=True, kw_only=True)
class LaunchOptions:
    """What ``launch`` (and ``inchworm.Swarm``) runs, by concern: the ``swarm``, its ``driver``, the ``faults`` to
    inject and the ``outputs``."""

    swarm: SwarmOptions = field(default_factory=SwarmOptions)
    driver: DriverOptions = field(default_factory=DriverOptions)
    faults: FaultOptions = field(default_factory=FaultOptions)
    outputs: OutputOptions = field(default_factory=OutputOptions)

    def __post_init__(self) -> None:
        if self.driver.name != "gateway":  # faults of the emulated radio and of its link processes
            for name in ("drop", "corrupt", "delay", "stall_link"):
                if getattr(self.faults, name):
                    raise OptionError(name, "is a fault of the emulated robots' radio and links: it needs the gateway driver", self.faults)
