"""The options of ``swarm bench localize`` and ``swarm bench select`` (``inchworm.bench.localize``,
``inchworm.bench.select``), in a module light to import: the commands make their flags from these fields
(``swarm_cli.schema``) before anything runs."""

from __future__ import annotations

from dataclasses import dataclass, field

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
