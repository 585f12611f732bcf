"""Wheel-speed profiles of an open-loop turn-then-drive command within the wheels' limits.

A command (turn rad, drive m) becomes two trapezoidal wheel-travel profiles played back in
time: first the turn in place (wheels at -w and +w, each travelling |turn| track / 2), then the
drive (both wheels at v, travelling the drive distance). Each phase accelerates at the wheels'
acceleration limit up to their speed limit (or less, a triangle, for a short phase), cruises and
decelerates to rest, so the commanded wheel speeds never exceed either limit. The robot executes
the speeds open-loop: what the ground and the other bodies make of them is the world's business.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np


@dataclass(frozen=True)
class Trapezoid:
    """Travel ``distance`` (>= 0) with speed limit ``vmax`` and acceleration limit ``amax``: speed at time t."""

    distance: float
    vmax: float
    amax: float

    @cached_property
    def peak(self) -> float:
        """The highest speed reached (vmax, or less when the distance is too short to reach it)."""
        return min(self.vmax, math.sqrt(self.distance * self.amax))

    @cached_property
    def duration(self) -> float:
        if self.distance <= 0:
            return 0.0
        v = self.peak
        return 2.0 * v / self.amax + (self.distance - v * v / self.amax) / v

    def speed_at(self, t: float) -> float:
        """``speed`` of one time (plain floats: the world asks every robot every step)."""
        total = self.duration
        if self.distance <= 0 or t < 0 or t > total:
            return 0.0
        return max(min(self.amax * t, self.peak, self.amax * (total - t)), 0.0)

    def speed(self, t: np.ndarray | float) -> np.ndarray:
        """Speed (>= 0) at times ``t`` (s) from the start; 0 outside [0, duration]."""
        t = np.asarray(t, dtype=float)
        if self.distance <= 0:
            return np.zeros_like(t)
        v, total = self.peak, self.duration
        out = np.minimum(np.minimum(self.amax * t, v), self.amax * (total - t))
        return np.where((t >= 0) & (t <= total), np.maximum(out, 0.0), 0.0)


@dataclass(frozen=True)
class TurnDriveProfile:
    """The wheel speeds (left, right; m/s) of the command (``turn_rad``, ``drive_m``) for wheels ``track_m`` apart."""

    turn_rad: float
    drive_m: float
    track_m: float
    vmax: float
    amax: float

    @cached_property
    def turn(self) -> Trapezoid:
        return Trapezoid(abs(self.turn_rad) * self.track_m / 2.0, self.vmax, self.amax)

    @cached_property
    def drive(self) -> Trapezoid:
        return Trapezoid(abs(self.drive_m), self.vmax, self.amax)

    @cached_property
    def duration(self) -> float:
        return self.turn.duration + self.drive.duration

    def in_drive(self, t: float) -> bool:
        """Whether time ``t`` falls in the drive phase."""
        return self.turn.duration <= t <= self.duration and self.drive_m != 0

    def wheels(self, t: float) -> tuple[float, float]:
        """(left, right) wheel speed at time ``t`` (s) since the command started."""
        t_turn = self.turn.duration
        if t < t_turn:
            w = self.turn.speed_at(t) * math.copysign(1.0, self.turn_rad)
            return -w, w
        v = self.drive.speed_at(t - t_turn) * math.copysign(1.0, self.drive_m)
        return v, v
