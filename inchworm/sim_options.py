"""The options of one simulated run (``SimOptions``: what ``swarm sim`` parses its flags from, ``swarm_cli.schema``) and
the trajectory they name; light to import (a command's parser reads it), ``inchworm.simulation`` runs them."""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from coordinator.localization.registry import DEFAULT_LOCALIZER
from coordinator.strategies import METHODS
from inchworm.limits import check_option_limits
from inchworm.options import check_at_least, check_localizers, default_selection
from runtime.errors import OptionError
from runtime.models.config import ModelConfig
from runtime.models.trajectory import Trajectory, body_spacing, random_trajectory
from runtime.paths import StrPath, coerce_paths

if TYPE_CHECKING:
    from coordinator.localization import Localizer
    from coordinator.selection.selector import SelectionConfig
    from coordinator.strategies import Strategy
    from runtime.world.params import PhysicsParams

WORLDS = ("model", "physics")  # the noise model's world, the rigid-body world (runtime.world)
OnProgress = Callable[[int, int], None]  # told (configurations done, of total)


@dataclass(frozen=True, kw_only=True)
class SimOptions:
    """One simulated run: ``method`` (a name of ``coordinator.strategies.METHODS`` or your own ``Strategy``) along
    ``trajectory`` (a ``Trajectory``, a trajectory JSON file, or None: a random one of ``robots`` robots and ``configs``
    configurations drawn with ``seed``); the noise ``model``, the ``localizer`` (a registered name or your own
    ``Localizer``, which a searching method's Monte Carlo simulates too), the anchor search (``selection``); the
    ``world`` (``"model"``: the robots move and sense by the noise model, as the planner assumes; ``"physics"``: a
    rigid-body world of ``physics`` parameters, default ``PhysicsParams.for_model(model)``, the ``physics`` extra) and
    the start estimate's uncertainty (``initial_delta_m``, ``initial_heading_sigma_rad``). Checked when made
    (``OptionError`` naming the field)."""

    trajectory: Trajectory | StrPath | None = field(default=None, metadata={"help": "trajectory JSON (docs/trajectory.md); default: a random one"})
    robots: int = field(default=10, metadata={"help": "robots of the random trajectory"})
    configs: int = field(default=5, metadata={"help": "configurations of the random trajectory"})
    method: str | Strategy = field(default="inchworm", metadata={"help": "motion strategy", "choices": METHODS})
    seed: int = field(default=0, metadata={"help": "seed of the trajectory, noise and search"})
    model: ModelConfig = field(default_factory=ModelConfig)
    localizer: str | Localizer = DEFAULT_LOCALIZER
    selection: SelectionConfig = field(default_factory=default_selection)
    world: str = "model"
    physics: PhysicsParams | None = field(default=None, metadata={"flag": "--physics-param"})
    initial_delta_m: float = 0.01
    initial_heading_sigma_rad: float = math.radians(2.0)

    def __post_init__(self) -> None:
        if self.trajectory is None:
            for name, least in (("robots", 2), ("configs", 1)):
                if getattr(self, name) < least:
                    raise OptionError(name, f"must be >= {least} for a random trajectory, got {getattr(self, name)}", self)
        elif not isinstance(self.trajectory, Trajectory):
            if not isinstance(self.trajectory, (str, os.PathLike)):
                raise OptionError("trajectory", f"must be a Trajectory or a trajectory JSON file, got {type(self.trajectory).__name__}", self)
            coerce_paths(self, "trajectory")
        if isinstance(self.method, str) and self.method not in METHODS:
            raise OptionError("method", f"must be one of {', '.join(METHODS)} (or a Strategy), got {self.method!r}", self)
        if isinstance(self.localizer, str):
            check_localizers(self, "localizer")
        if self.world not in WORLDS:
            raise OptionError("world", f"must be 'model' or 'physics', got {self.world!r}", self)
        if self.physics is not None and self.world != "physics":
            raise OptionError("physics", "sets the physical world: it needs `world` physics", self)
        check_at_least(self, "seed", 0)
        check_option_limits(self)
        for name in ("initial_delta_m", "initial_heading_sigma_rad"):
            if not getattr(self, name) >= 0:
                raise OptionError(name, f"must be >= 0, got {getattr(self, name)}", self)

    def run_trajectory(self) -> Trajectory:
        """The trajectory the run follows: ``trajectory``, loaded if it is a file, or the random one it draws."""
        return resolve_trajectory(self.trajectory, self.robots, self.configs, self.seed, self.model)


def resolve_trajectory(trajectory: Trajectory | StrPath | None, robots: int, configs: int, seed: int, model: ModelConfig) -> Trajectory:
    """``trajectory``, loaded if it is a file name, or (None) the random one of ``simulate``."""
    if trajectory is None:
        return random_trajectory(robots, configs, np.random.default_rng(seed), sensing_range=model.sensing_range_m, **body_spacing(model))
    return trajectory if isinstance(trajectory, Trajectory) else Trajectory.load(Path(trajectory))


__all__ = ["OnProgress", "SimOptions", "WORLDS", "resolve_trajectory"]
