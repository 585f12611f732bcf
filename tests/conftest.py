"""Shared fixtures: noise-free and default model configurations."""

from __future__ import annotations

import pytest
from hypothesis import HealthCheck, settings

from runtime.config import ModelConfig

# Behaviour, not speed: no per-example deadline and no "input generation is slow" failure
# (a busy 2-core machine can stall any draw for a second).
settings.register_profile("behaviour", deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.load_profile("behaviour")


@pytest.fixture
def cfg() -> ModelConfig:
    return ModelConfig()


@pytest.fixture
def exact_sensing() -> ModelConfig:
    """Default motion noise, noise-free sensing."""
    return ModelConfig(range_sigma_m=0.0, bearing_sigma_rad=0.0)
