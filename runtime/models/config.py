"""The one configuration object for every noise and sensing parameter.

The paper states no noise levels; the defaults below are this project's choice and
every command that simulates exposes them as options (see ``swarm_cli.options``).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, fields

from runtime.errors import SwarmInputError


@dataclass(frozen=True)
class ModelConfig:
    """Motion and sensing model parameters (SI units: metres, radians).

    Motion (turn-then-drive, no odometry): the executed turn is the commanded turn
    plus N(0, ``turn_sigma_rad``); the executed distance is the commanded distance
    times (1 + N(0, ``drive_sigma_frac``)), i.e. sigma = 5 % of the distance.

    Sensing: robot i observes robot j when |x_j - x_i| <= ``sensing_range_m``; the
    range gets N(0, ``range_sigma_m``), the bearing (in i's body frame)
    N(0, ``bearing_sigma_rad``); each observation is lost with ``dropout_prob``.

    Bodies: every robot is a disc of radius ``robot_radius_m`` (default: the paper's 22 x 20 mm
    mROBerTO, 0.011 m); plans keep bodies apart and runs count contacts
    (``runtime.models.bodies``, docs/bodies.md). 0 is the paper's point robots.
    """

    turn_sigma_rad: float = math.radians(3.0)
    drive_sigma_frac: float = 0.05
    range_sigma_m: float = 0.01
    bearing_sigma_rad: float = math.radians(2.0)
    sensing_range_m: float = 0.5
    dropout_prob: float = 0.0
    robot_radius_m: float = field(default=0.011, metadata={"flag": "--robot-radius"})

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
                raise SwarmInputError(f"ModelConfig.{f.name} must be a finite number >= 0, got {value!r}")
        if self.sensing_range_m <= 0:
            raise SwarmInputError(f"ModelConfig.sensing_range_m must be > 0, got {self.sensing_range_m!r}")
        if self.dropout_prob >= 1:
            raise SwarmInputError(f"ModelConfig.dropout_prob must be in [0, 1), got {self.dropout_prob!r}")

    def to_dict(self) -> dict[str, float]:
        """Plain dict, e.g. for run metadata."""
        return asdict(self)
