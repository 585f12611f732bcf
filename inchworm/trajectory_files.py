"""Write a random trajectory file, or check one (``swarm trajectory new|check``; docs/trajectory.md).

``new_trajectory`` writes the random trajectory ``swarm sim`` / ``swarm launch`` would make for the same options
(``runtime.models.trajectory.random_trajectory``); ``check_trajectory`` loads a file and checks what the runtime will
check before a run: the format and that every configuration, the initial one included, is connected within the
sensing range. Cheap to import (``swarm trajectory --help`` builds its flags from the options): numpy when one runs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from inchworm.limits import check_option_limits
from runtime.errors import OptionError, SwarmInputError
from runtime.models.config import ModelConfig
from runtime.paths import StrPath, coerce_paths

if TYPE_CHECKING:
    from runtime.models.trajectory import Trajectory

_SENSING_HELP = "sensing range in m every configuration must stay connected within"


def _check_positive(options: object, *names: str) -> None:
    for name in names:
        value = getattr(options, name)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not (math.isfinite(value) and value > 0):
            raise OptionError(name, f"must be a finite number > 0, got {value!r}", options)


@dataclass(frozen=True, kw_only=True)
class NewTrajectoryOptions:
    """Settings of ``new_trajectory`` (``swarm trajectory new``'s flags): the JSON ``file`` to write, ``robots``,
    ``configs`` (desired configurations), the ``seed``, the ``step`` (m) the swarm moves per configuration and the
    ``sensing_range`` (m) every configuration stays connected within."""

    file: StrPath
    robots: int = field(default=10, metadata={"help": "robots"})
    configs: int = field(default=5, metadata={"help": "desired configurations"})
    seed: int = field(default=0, metadata={"help": "seed of the random trajectory"})
    step: float = field(default=0.3, metadata={"help": "how far the swarm moves per configuration, m"})
    sensing_range: float = field(default=ModelConfig().sensing_range_m, metadata={"help": _SENSING_HELP})

    def __post_init__(self) -> None:
        coerce_paths(self, "file")
        for name in ("robots", "configs", "seed"):
            if isinstance(getattr(self, name), bool) or not isinstance(getattr(self, name), int):
                raise OptionError(name, f"must be an integer, got {getattr(self, name)!r}", self)
        check_option_limits(self)
        _check_positive(self, "step", "sensing_range")


@dataclass(frozen=True, kw_only=True)
class CheckTrajectoryOptions:
    """Settings of ``check_trajectory`` (``swarm trajectory check``'s flags): the JSON ``file`` and the
    ``sensing_range`` (m) every configuration must stay connected within."""

    file: StrPath
    sensing_range: float = field(default=ModelConfig().sensing_range_m, metadata={"help": _SENSING_HELP})

    def __post_init__(self) -> None:
        coerce_paths(self, "file")
        _check_positive(self, "sensing_range")


@dataclass(frozen=True)
class TrajectoryFile:
    """A trajectory file written or checked: its ``file``, the ``trajectory`` and its ``summary`` (robots,
    configurations, the sensing range in m, the robots' motion per configuration, mean and max in m);
    ``to_json()`` is what ``swarm trajectory new|check --json`` prints."""

    file: Path
    trajectory: Trajectory
    summary: dict[str, float]

    def to_json(self) -> dict[str, Any]:
        return {"file": str(self.file), **self.summary}


def new_trajectory(options: NewTrajectoryOptions | None = None, /, **keywords: Any) -> TrajectoryFile:
    """Write the random trajectory of the ``NewTrajectoryOptions`` ``options`` (or of the keywords that make them:
    ``new_trajectory(file="t.json", robots=6)``) and return it with its summary."""
    import numpy as np  # noqa: PLC0415

    from runtime.models.trajectory import random_trajectory  # noqa: PLC0415

    o = _options_of(NewTrajectoryOptions, options, keywords)
    traj = random_trajectory(o.robots, o.configs, np.random.default_rng(o.seed), sensing_range=o.sensing_range, step=o.step)
    file = Path(o.file)
    file.parent.mkdir(parents=True, exist_ok=True)
    traj.save(file)
    return TrajectoryFile(file, traj, traj.describe(o.sensing_range))


def check_trajectory(options: CheckTrajectoryOptions | StrPath, /, **keywords: Any) -> TrajectoryFile:
    """Load and check the trajectory file of the ``CheckTrajectoryOptions`` ``options`` (or the file and the
    keywords: ``check_trajectory("t.json", sensing_range=0.6)``): ``SwarmInputError`` naming the file for a bad row
    or a configuration not connected within the sensing range."""
    from runtime.models.trajectory import Trajectory, validate_connected  # noqa: PLC0415

    if not isinstance(options, CheckTrajectoryOptions):
        options = CheckTrajectoryOptions(file=options, **keywords)
        keywords = {}
    o = _options_of(CheckTrajectoryOptions, options, keywords)
    file = Path(o.file)
    traj = Trajectory.load(file)
    try:
        validate_connected(traj, o.sensing_range)
    except SwarmInputError as exc:
        raise SwarmInputError(f"trajectory {file}: {exc}") from None
    return TrajectoryFile(file, traj, traj.describe(o.sensing_range))


def _options_of(cls: Any, options: Any, keywords: dict[str, Any]) -> Any:
    """The options ``cls`` given, or those its keywords make (a ``TypeError`` for both)."""
    if options is None:
        return cls(**keywords)
    if keywords:
        raise TypeError(f"takes {cls.__name__} or keywords, not both: dataclasses.replace(options, ...) changes some")
    return options
