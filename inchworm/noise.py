"""Noise scaling of the studies: motion (turn and drive) and sensing (range and bearing) sigmas by factors."""

from __future__ import annotations

from dataclasses import replace

from runtime.models.config import ModelConfig


def scaled(base: ModelConfig, motion: float = 1.0, sensing: float = 1.0) -> ModelConfig:
    """``base`` with the turn and drive sigmas times ``motion`` and the range and bearing sigmas times ``sensing``."""
    return replace(base, turn_sigma_rad=base.turn_sigma_rad * motion, drive_sigma_frac=base.drive_sigma_frac * motion,
                   range_sigma_m=base.range_sigma_m * sensing, bearing_sigma_rad=base.bearing_sigma_rad * sensing)
