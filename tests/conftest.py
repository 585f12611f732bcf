"""Shared fixtures: noise-free and default model configurations."""

from __future__ import annotations

import pytest

from runtime.config import ModelConfig


@pytest.fixture
def cfg() -> ModelConfig:
    return ModelConfig()


@pytest.fixture
def exact_sensing() -> ModelConfig:
    """Default motion noise, noise-free sensing."""
    return ModelConfig(range_sigma_m=0.0, bearing_sigma_rad=0.0)
