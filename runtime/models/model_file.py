"""Noise model files (TOML): the ``ModelConfig`` values a lab measured for its robots (docs/calibration.md).

    [model]
    turn_sigma_deg = 7.0       # the units of the flags of the same names
    drive_sigma_frac = 0.12
    range_sigma_m = 0.03
    bearing_sigma_deg = 5.0
    dropout = 0.2
    sensing_range_m = 0.35
    robot_radius_m = 0.011     # the robots' body radius (docs/bodies.md)

    [fit]                      # optional, written by `swarm calibrate`: where the numbers come from
    ...

Every key of ``[model]`` is optional (a missing one keeps the project's default); ``[fit]``
is informational and not read back into the model. ``swarm calibrate`` writes these files
and every command that simulates or plans reads one with ``--model FILE``; explicit flags
override the file's values.
"""

from __future__ import annotations

import json
import math
import tomllib
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path
from typing import Any

from runtime.errors import OptionError, SwarmInputError
from runtime.models.config import ModelConfig
from runtime.paths import StrPath

# key -> (ModelConfig field, to SI, from SI, lowest value allowed, whether the lowest value is allowed, upper bound exclusive)
KEYS: dict[str, tuple[str, Any, Any, float, bool, float]] = {
    "turn_sigma_deg": ("turn_sigma_rad", math.radians, math.degrees, 0.0, True, math.inf),
    "drive_sigma_frac": ("drive_sigma_frac", float, float, 0.0, True, math.inf),
    "range_sigma_m": ("range_sigma_m", float, float, 0.0, True, math.inf),
    "bearing_sigma_deg": ("bearing_sigma_rad", math.radians, math.degrees, 0.0, True, math.inf),
    "dropout": ("dropout_prob", float, float, 0.0, True, 1.0),
    "sensing_range_m": ("sensing_range_m", float, float, 0.0, False, math.inf),
    "robot_radius_m": ("robot_radius_m", float, float, 0.0, True, math.inf),
}
SECTIONS = ("model", "fit")


def model_values(cfg: ModelConfig) -> dict[str, float]:
    """``cfg`` in the file's keys and units (degrees for the angles)."""
    return {key: to_user(getattr(cfg, field)) for key, (field, _, to_user, *_rest) in KEYS.items()}


def parse_model(doc: Mapping[str, Any], source: str, base: ModelConfig = ModelConfig(), parameter: str | None = None) -> ModelConfig:
    """``base`` with the ``[model]`` values of the parsed TOML ``doc``; errors name ``source`` and the key (with
    ``parameter``: an ``OptionError`` of that parameter, whose value ``source`` is)."""
    def error(problem: str) -> SwarmInputError:
        return OptionError(parameter, f"{source}: {problem}") if parameter else SwarmInputError(f"{source}: {problem}")

    unknown = sorted(set(doc) - set(SECTIONS))
    if unknown:
        raise error(f"unknown table or key {unknown[0]!r} (a model file has [model] and optionally [fit])")
    table = doc.get("model")
    if not isinstance(table, Mapping):
        raise error(f"no [model] table (keys {', '.join(KEYS)})")
    changes: dict[str, float] = {}
    for key, value in table.items():
        if key not in KEYS:
            raise error(f"unknown key model.{key} (known: {', '.join(KEYS)})")
        field, to_si, _, low, low_ok, high = KEYS[key]
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise error(f"model.{key} must be a finite number, got {value!r}")
        if value < low or (value == low and not low_ok) or value >= high:
            bound = f"{'>=' if low_ok else '>'} {low:g}" + ("" if math.isinf(high) else f" and < {high:g}")
            raise error(f"model.{key} must be {bound}, got {value!r}")
        changes[field] = to_si(float(value))
    return replace(base, **changes)


def load_model(path: StrPath, base: ModelConfig = ModelConfig()) -> ModelConfig:
    """The model of the TOML file ``path`` (missing keys from ``base``); ``SwarmInputError`` naming the file and key."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise OptionError("model", f"{path}: cannot read it: {getattr(exc, 'strerror', None) or exc}") from None
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise OptionError("model", f"{path}: not TOML: {exc}") from None
    return parse_model(doc, str(path), base, "model")


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        if isinstance(value, float) and not math.isfinite(value):
            return "inf" if value > 0 else ("-inf" if value < 0 else "nan")
        return repr(int(value)) if isinstance(value, int) else repr(float(value))
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    return json.dumps(str(value))  # a JSON string is a TOML basic string


def model_toml(cfg: ModelConfig, fit: Mapping[str, Mapping[str, Any]] | None = None, header: str = "") -> str:
    """The model file text of ``cfg``, with the ``[fit.<name>]`` tables ``fit`` (flat values or lists) after it."""
    lines = [f"# {line}" for line in header.splitlines()]
    lines += ["[model]", *(f"{k} = {_toml_value(v)}" for k, v in model_values(cfg).items())]
    for name, table in (fit or {}).items():
        lines += ["", f"[fit.{name}]", *(f"{k} = {_toml_value(v)}" for k, v in table.items() if v is not None)]
    return "\n".join(lines) + "\n"
