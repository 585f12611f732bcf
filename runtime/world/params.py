"""Parameters of the physical world (SI units), with where each default comes from (docs/physics.md).

The paper (Sec. 6.2) names the robot, mROBerTO 2.0, a millimetre-scale differential-drive robot with
IR proximity sensing, but states no size, mass, speed or friction. The defaults below are therefore
assumptions for a robot of that class, chosen to be plausible and stated as such; every one can be
set (``PhysicsParams(...)``, ``--physics-param NAME=VALUE``). The body radius and the sensing range are
taken from the run's ``ModelConfig`` (``PhysicsParams.for_model``) so the world and the planner agree
on what a body and a neighbour are; everything else is the world's own and is *not* the noise model.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace

from runtime.errors import OptionError, SwarmInputError
from runtime.models.config import ModelConfig

GRAVITY_M_S2 = 9.81


@dataclass(frozen=True)
class PhysicsParams:
    """A disc robot with a differential drive, and its sensor (SI units).

    Body: ``radius_m`` (default 0.011 m: the half-diagonal, 11.3 mm, of a ~16 mm x 16 mm footprint,
    rounded to the planner's default radius), ``mass_kg`` (0.01 kg, assumed), contact ``elasticity``
    (0.2) and robot-robot ``contact_friction`` (0.3).

    Drive: wheels ``track_m`` apart (0.014 m, assumed for a 16 mm wide body); wheel speed at most
    ``max_wheel_speed_m_s`` (0.05 m/s, assumed) and changing at most ``max_wheel_accel_m_s2``
    (0.25 m/s^2, assumed); the ground transmits at most ``traction_mu`` m g (0.6, rubber on a lab
    floor) of drive or lateral force, beyond which the wheels slip; a standing robot resists being
    pushed with ``hold_mu`` m g (0.3: geared micro motors back-drive). Each command's wheel speeds are
    scaled by 1 + N(0, ``wheel_scale_sigma``) common to both wheels (0.03: wheel radius, floor) and
    each wheel by another 1 + N(0, ``wheel_diff_sigma``) (0.002: the two wheels differ, the robot curves).

    Sensor: neighbours within ``sensing_range_m`` (the model's), inside a field of view of
    ``fov_rad`` centred on the heading (2 pi: all round, as mROBerTO's ring of IR sensors), whose
    centre is not hidden behind a third body (``occlusion``); range noise N(0, ``range_sigma_m`` +
    ``range_sigma_frac`` d) (5 mm + 2 % of the distance d: IR intensity ranging degrades with
    distance), bearing noise N(0, ``bearing_sigma_rad``) (2 deg), each sighting lost with ``dropout_prob``.

    Integration: fixed steps of ``dt_s`` (5 ms).
    """

    radius_m: float = 0.011
    mass_kg: float = 0.01
    elasticity: float = 0.2
    contact_friction: float = 0.3
    track_m: float = 0.014
    max_wheel_speed_m_s: float = 0.05
    max_wheel_accel_m_s2: float = 0.25
    traction_mu: float = 0.6
    hold_mu: float = 0.3
    wheel_scale_sigma: float = 0.03
    wheel_diff_sigma: float = 0.002
    sensing_range_m: float = 0.5
    fov_rad: float = 2.0 * math.pi
    occlusion: bool = True
    range_sigma_m: float = 0.005
    range_sigma_frac: float = 0.02
    bearing_sigma_rad: float = math.radians(2.0)
    dropout_prob: float = 0.0
    dt_s: float = 0.005

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name == "occlusion":
                if not isinstance(value, bool):
                    raise SwarmInputError(f"PhysicsParams.occlusion must be true or false, got {value!r}")
                continue
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
                raise SwarmInputError(f"PhysicsParams.{f.name} must be a finite number >= 0, got {value!r}")
        for name in ("radius_m", "mass_kg", "track_m", "max_wheel_speed_m_s", "max_wheel_accel_m_s2", "traction_mu",
                     "sensing_range_m", "fov_rad", "dt_s"):
            if getattr(self, name) <= 0:
                raise SwarmInputError(f"PhysicsParams.{name} must be > 0, got {getattr(self, name)!r}")
        if self.fov_rad > 2.0 * math.pi:
            raise SwarmInputError(f"PhysicsParams.fov_rad must be at most 2 pi, got {self.fov_rad!r}")
        if self.dropout_prob >= 1:
            raise SwarmInputError(f"PhysicsParams.dropout_prob must be in [0, 1), got {self.dropout_prob!r}")
        if self.dt_s > 0.05:
            raise SwarmInputError(f"PhysicsParams.dt_s must be at most 0.05 s, got {self.dt_s!r}")

    @classmethod
    def for_model(cls, model: ModelConfig, **overrides: float | bool) -> PhysicsParams:
        """The defaults with the model's body radius and sensing range (a robot of radius 0 gets 1 mm), then ``overrides``."""
        base = cls(radius_m=model.robot_radius_m or 0.001, sensing_range_m=model.sensing_range_m)
        return base.with_overrides(overrides)

    def with_overrides(self, overrides: dict[str, float | bool]) -> PhysicsParams:
        """A copy with the named fields replaced (``SwarmInputError`` naming an unknown field)."""
        names = {f.name for f in fields(self)}
        unknown = sorted(set(overrides) - names)
        if unknown:
            raise SwarmInputError(f"unknown physics parameter(s) {unknown}; known: {', '.join(sorted(names))}")
        return replace(self, **overrides)  # type: ignore[arg-type]  # checked by __post_init__

    @property
    def drive_force_n(self) -> float:
        """The largest force the wheels transmit (N)."""
        return self.traction_mu * self.mass_kg * GRAVITY_M_S2

    @property
    def hold_force_n(self) -> float:
        """The force a standing robot resists a push with (N)."""
        return self.hold_mu * self.mass_kg * GRAVITY_M_S2

    def to_dict(self) -> dict[str, float | bool]:
        return asdict(self)


def parse_physics_params(pairs: list[str], model: ModelConfig) -> PhysicsParams:
    """``NAME=VALUE`` texts (``--physics-param``) over ``PhysicsParams.for_model(model)``; errors name the pair."""
    overrides: dict[str, float | bool] = {}
    for pair in pairs:
        name, sep, text = pair.partition("=")
        name = name.strip()
        if not sep or not name:
            raise OptionError("physics_param", f"must be NAME=VALUE, got {pair!r}")
        if name == "occlusion":
            if text.strip().lower() not in ("true", "false", "1", "0", "yes", "no"):
                raise OptionError("physics_param", f"{pair}: occlusion is true or false")
            overrides[name] = text.strip().lower() in ("true", "1", "yes")
            continue
        try:
            overrides[name] = float(text)
        except ValueError:
            raise OptionError("physics_param", f"{pair}: {text!r} is not a number") from None
    return PhysicsParams.for_model(model, **overrides)
