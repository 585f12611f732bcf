"""The options of ``swarm bench localize``, ``select``, ``record``, ``runtime``, ``gateway``, ``faults``, ``physics`` and
``collisions`` and ``envelope`` (``inchworm.bench.localize``, ...),
in a module light to import: the commands make their flags from these fields (``swarm_cli.schema``) before anything
runs."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from coordinator.strategies import METHODS
from inchworm.options import RunOptions
from runtime.errors import OptionError
from runtime.models.config import ModelConfig


@dataclass(frozen=True)
class LocalizeBenchOptions:
    sizes: tuple[int, ...] = field(default=(10, 100, 1000), metadata={"help": "comma-separated swarm sizes", "minimum": 2})
    trials: int = field(default=5, metadata={"help": "random steps per size"})
    repeats: int = field(default=5, metadata={"help": "timing repetitions per step"})
    seed: int = field(default=0, metadata={"help": "trial t uses seed + t"})
    gtsam: bool = field(default=True, metadata={"flag": "--no-gtsam", "help": "skip the GTSAM reference even if it is installed"})
    model: ModelConfig = field(default_factory=ModelConfig)
    still_prior_m: float | None = field(default=None, metadata={  # None: the movers' 0.02 m
        "flag": "--still-prior", "metavar": "M",
        "help": "prior position std in m of the robots that do not move (anchors); default: the movers' 0.02 m"})

    def __post_init__(self) -> None:
        if self.still_prior_m is not None and not self.still_prior_m > 0:
            raise OptionError("still_prior_m", f"must be > 0 m, got {self.still_prior_m}", self)


@dataclass(frozen=True)
class SelectBenchOptions:
    sizes: tuple[int, ...] = field(default=(10, 30, 100), metadata={"help": "comma-separated swarm sizes", "minimum": 2})
    repeats: int = field(default=3, metadata={"help": "selections per size, each on a new random step"})
    seed: int = field(default=0, metadata={"help": "seed of the random steps"})
    one_core: bool = True  # --all-cores: False
    run: RunOptions = field(default_factory=RunOptions)
    search_all: bool = field(default=False, metadata={
        "help": "search every count (no outer-loop bound), to time searched selections"})  # every count through the inner loop


@dataclass(frozen=True)
class RecordBenchOptions:
    sizes: tuple[int, ...] = field(default=(10, 50), metadata={"flag": "--robots", "metavar": "ROBOTS", "help": "comma-separated swarm sizes",
                                                               "minimum": 1})
    steps: int = field(default=40, metadata={"help": "steps of messages recorded per run"})
    steps_per_config: int = field(default=4, metadata={"help": "steps per configuration: one PlanMessage each"})
    repeats: int = field(default=3, metadata={"help": "recordings per size and mode, median reported"})
    step_ms: tuple[float, ...] = field(default=(20.0, 100.0), metadata={  # coordination time of a step without recording (ms)
        "help": "coordination time of one step without recording, ms: one value or one per size "
                "(default 20,100: the runtime's targets for 10 and 50 agents)", "own_default": True})
    seed: int = field(default=0, metadata={"help": "seed of the positions and measurements"})


RUNTIME_METHODS = ("no-anchors", "ref57")  # the fixed plans ``swarm bench runtime`` times


@dataclass(frozen=True)
class RuntimeBenchOptions:
    agents: tuple[int, ...] = field(default=(10, 50), metadata={"help": "comma-separated numbers of robot agents", "minimum": 2})
    agents_per_process: int | None = field(default=None, metadata={  # None: as swarm launch
        "help": "robot agents hosted by one process (default as swarm launch: 1 up to 50 robots, else up to 50)"})
    steps: int = field(default=20, metadata={"help": "steps timed per swarm size"})
    method: str = field(default="no-anchors", metadata={  # a fixed plan: no-anchors (all move each step) or ref57
        "help": "fixed plan (default no-anchors: all move each step)", "own_default": True, "choices": RUNTIME_METHODS})
    seed: int = field(default=0, metadata={"help": "seed of the trajectory and the noise"})
    rtt_count: int = field(default=200, metadata={"help": "pings of the raw Zenoh round trip"})
    start_timeout_s: float = field(default=120.0, metadata={"flag": "--start-timeout", "metavar": "START_TIMEOUT",
                                                            "help": "seconds to wait for all agents"})
    step_timeout_s: float = field(default=10.0, metadata={"flag": "--step-timeout", "metavar": "STEP_TIMEOUT",
                                                          "help": "seconds to wait for a step's answers"})
    localizer: str = "paper"
    model: ModelConfig = field(default_factory=ModelConfig)


@dataclass(frozen=True)
class GatewayBenchOptions:
    robots: int = field(default=10, metadata={"help": "agents of the step-time comparison"})
    steps: int = field(default=60, metadata={"help": "steps timed per driver and round"})
    rounds: int = field(default=2, metadata={"help": "rounds of sim then gateway, steps pooled per driver"})
    frames: int = field(default=200_000, metadata={"help": "frames through the codec"})
    commands: int = field(default=300, metadata={"help": "commands of the pty round trip"})
    seed: int = field(default=0, metadata={"help": "seed of the trajectory and noise"})
    localizer: str = "paper"
    model: ModelConfig = field(default_factory=ModelConfig)


@dataclass(frozen=True)
class FaultsBenchOptions:
    seeds: int = field(default=10, metadata={"help": "seeds (runs) per lost-robot and gateway row"})
    fuzz: int = field(default=10_000, metadata={"help": "hostile messages sent during the fuzz run"})
    gateway_rows: tuple[tuple[float, float, float], ...] = ((0.05, 0.05, 0.05), (0.2, 0.0, 0.0))  # radio faults (drop, corrupt, delay_s)
    flood: int = field(default=3000, metadata={"help": "idle TCP connections held on the TLS router's public listener during the stops"})
    flood_s: float = field(default=60.0, metadata={  # how long the flood lasts (stops sampled during it and min(flood_s, 60) s after it)
        "help": "seconds the flood lasts; a stop a second during it and min(FLOOD_S, 60) s after it"})


@dataclass(frozen=True)
class PhysicsBenchOptions:
    robots: int = field(default=10, metadata={"help": "n_r"})
    trajectories: int = field(default=10, metadata={"help": "random trajectories"})
    configs: int = field(default=10, metadata={"help": "configurations per trajectory"})
    method: str = field(default="inchworm", metadata={"help": "motion strategy", "choices": METHODS})
    seed: int = field(default=0, metadata={"help": "trajectory t uses seed + t"})
    workers: int = 1
    run: RunOptions = field(default_factory=RunOptions)
    physics: tuple[str, ...] = field(default=(), metadata={  # NAME=VALUE
        "flag": "--physics-param", "repeat": True, "metavar": "NAME=VALUE",
        "help": "a parameter of the physical world (runtime.world.params.PhysicsParams), repeatable"})


COLLISION_LOCALIZERS = ("paper", "joint")  # the localizers ``swarm bench collisions`` runs
COLLISION_NOISE_SCALES = (1.0, 3.0, 5.58)  # motion noise x1, x3 (9 deg, 0.15) and x5.58 (16.74 deg, 0.279)


@dataclass(frozen=True, kw_only=True)
class CollisionsBenchOptions:
    robots: int = field(default=10, metadata={"help": "n_r"})
    trajectories: int = field(default=20, metadata={"help": "random trajectories"})
    configs: int = field(default=20, metadata={"help": "configurations per trajectory"})
    methods: tuple[str, ...] = field(default=METHODS, metadata={"help": "comma-separated methods (default: all)", "own_default": True})
    localizers: tuple[str, ...] = field(default=("paper",), metadata={"help": "comma-separated localizers: paper, joint"})
    seed: int = field(default=0, metadata={"help": "trajectory t uses seed + t"})
    workers: int = 1
    noise_scales: tuple[float, ...] = field(default=COLLISION_NOISE_SCALES, metadata={  # factors of the model's turn and drive noise
        "help": "comma-separated factors of the motion noise (turn and drive sigma) run in turn"})
    run: RunOptions = field(default_factory=RunOptions)  # its localizer is not used: ``localizers`` are

    def __post_init__(self) -> None:
        if self.run.model.robot_radius_m <= 0:
            raise OptionError("robot_radius_m", "must be > 0 for counting contacts between bodies", self.run.model)
        for name, low in (("trajectories", 1), ("configs", 1), ("robots", 2), ("workers", 1)):
            if getattr(self, name) < low:
                raise OptionError(name, f"must be >= {low}, got {getattr(self, name)}", self)
        if not self.methods or any(m not in METHODS for m in self.methods):
            raise OptionError("methods", f"must list methods of {', '.join(METHODS)}, got {','.join(self.methods)!r}", self)
        if not self.localizers or any(v not in COLLISION_LOCALIZERS for v in self.localizers):
            raise OptionError("localizers", f"must list {' and/or '.join(COLLISION_LOCALIZERS)}, got {','.join(self.localizers)!r}", self)
        if not self.noise_scales or not all(math.isfinite(k) and k > 0 for k in self.noise_scales):
            raise OptionError("noise_scales", f"must list factors > 0, got {','.join(map(str, self.noise_scales))!r}", self)


@dataclass(frozen=True, kw_only=True)
class EnvelopeBenchOptions:
    """The matrix (every combination of the four axes) and the sizes of each row's runs."""

    noise_scales: tuple[float, ...] = field(default=(1.0, 3.0, 5.58), metadata={"help": "motion noise multiples"})
    robots: tuple[int, ...] = field(default=(10, 30), metadata={"help": "swarm sizes"})
    localizers: tuple[str, ...] = field(default=("paper", "joint"), metadata={"help": "comma-separated localizers"})
    sensing_ranges_m: tuple[float, ...] = field(default=(0.5, 3.0), metadata={"flag": "--sensing-ranges", "metavar": "SENSING_RANGES",
                                                                              "help": "sensing ranges in m"})
    trajectories: int = field(default=4, metadata={"help": "in-process runs per row"})
    configs: int = field(default=8, metadata={"help": "configurations per in-process run"})
    distributed_configs: int = field(default=3, metadata={"help": "configurations of each row's distributed run"})
    distributed: bool = field(default=True, metadata={  # False: in-process rows only (replay/takeover None)
        "flag": "--no-distributed", "help": "in-process rows only (replay and takeover not measured)"})
    seed: int = field(default=0, metadata={"help": "trajectory t uses seed + t"})
    workers: int = 1  # processes for the in-process runs

    def __post_init__(self) -> None:
        from coordinator.localization.registry import localizer_names  # noqa: PLC0415

        for name in ("trajectories", "configs", "distributed_configs", "workers"):
            if getattr(self, name) < 1:
                raise OptionError(name, f"must be >= 1, got {getattr(self, name)}", self)
        for name in ("noise_scales", "sensing_ranges_m"):
            if not getattr(self, name) or not all(math.isfinite(v) and v > 0 for v in getattr(self, name)):
                raise OptionError(name, f"must list numbers > 0, got {','.join(map(str, getattr(self, name)))!r}", self)
        if not self.robots or any(n < 2 for n in self.robots):
            raise OptionError("robots", f"must list sizes >= 2, got {','.join(map(str, self.robots))!r}", self)
        unknown = [name for name in self.localizers if name not in localizer_names()]
        if not self.localizers or unknown:
            raise OptionError("localizers", f"unknown {','.join(unknown)!r}; choose from {', '.join(localizer_names())}", self)
