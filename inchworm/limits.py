"""Limits every run checks before it starts (sizes, seeds) and the typed model / anchor-search settings
made from the values a user gave. Cheap to import: ``swarm --help`` loads it."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from runtime.errors import OptionError, SwarmInputError
from runtime.models.config import ModelConfig

if TYPE_CHECKING:  # imported where used: scipy only when a run starts
    from coordinator.selection.selector import SelectionConfig

MAX_SEED = 2**63 - 1  # numpy seeds must be >= 0; int64 keeps seed + t and [seed, c] seeds exact
MAX_ROBOTS = 10_000  # simulated robots (swarm sim, compare, studies): 10,000 take ~150 s of CPU a configuration (docs/benchmarks.md)
MAX_LAUNCHED_ROBOTS = 1000  # agent processes' robots on one host (swarm launch -n): 500 measured (swarm bench runtime)
MAX_CONFIGS = 10_000  # configurations of a random trajectory
MAX_TRAJECTORIES = 10_000  # random trajectories of a comparison or study
LIMITS = {  # option dest -> (flag, least (None: the run checks it), most, what is limited)
    "seed": ("--seed", 0, MAX_SEED, "numpy seeds are >= 0 and int64"),
    "configs": ("--configs", None, MAX_CONFIGS, "configurations of a random trajectory"),
    "trajectories": ("--trajectories", 1, MAX_TRAJECTORIES, "random trajectories"),
}
MODEL_FLAGS = {  # option dest -> (ModelConfig field, to SI, flag)
    "turn_sigma_deg": ("turn_sigma_rad", math.radians, "--turn-sigma-deg"),
    "drive_sigma_frac": ("drive_sigma_frac", float, "--drive-sigma-frac"),
    "range_sigma": ("range_sigma_m", float, "--range-sigma"),
    "bearing_sigma_deg": ("bearing_sigma_rad", math.radians, "--bearing-sigma-deg"),
    "sensing_range": ("sensing_range_m", float, "--sensing-range"),
    "dropout": ("dropout_prob", float, "--dropout"),
    "robot_radius": ("robot_radius_m", float, "--robot-radius"),
}


def _limits(launched: bool) -> dict[str, tuple[str, int | None, int, str]]:
    limits = dict(LIMITS)
    limits["robots"] = ("-n/--robots" if launched else "--robots", None, MAX_LAUNCHED_ROBOTS if launched else MAX_ROBOTS,
                        "robots launched as agent processes on one host" if launched else "simulated robots")
    limits["trajectory_seed"] = LIMITS["seed"]
    return limits


def _beyond(dest: str, value: object, launched: bool) -> str | None:
    """What is wrong with ``value`` of the option ``dest`` (``value: must be between ...``), None if it is within its limits
    (or not a limited integer)."""
    limit = _limits(launched).get(dest)
    if limit is None or not isinstance(value, int) or isinstance(value, bool):
        return None
    _, least, most, what = limit
    if (least is None or value >= least) and value <= most:
        return None
    shown = "2^63 - 1" if most == MAX_SEED else f"{most}"
    return f"{value}: at most {shown} ({what})" if least is None else f"{value}: must be between {least} and {shown} ({what})"


def check_limits(values: Mapping[str, Any], *, launched: bool = False) -> None:
    """``SwarmInputError`` naming the flag and its limits for a negative seed or an absurd size among ``values``
    (option dest -> value). ``robots``: at most ``MAX_ROBOTS`` simulated or ``MAX_LAUNCHED_ROBOTS`` launched as
    agent processes (``launched``; the least, 2, is checked where the swarm is made)."""
    for dest, (flag, _, _, _) in _limits(launched).items():
        problem = _beyond(dest, values.get(dest), launched)
        if problem is not None:
            raise SwarmInputError(f"{flag} {problem}")


def check_option_limits(options: Any, *, launched: bool = False) -> None:
    """In an options dataclass's ``__post_init__``: ``OptionError`` naming the field for a negative seed or an absurd
    size among its fields ``robots``, ``configs``, ``trajectories``, ``seed``, ``trajectory_seed`` (``check_limits``'s
    limits)."""
    for f in dataclasses.fields(options):
        problem = _beyond(f.name, getattr(options, f.name), launched)
        if problem is not None:
            raise OptionError(f.name, problem, options)


def check_swarm_size(n: int, source: str, *, launched: bool = False, parameter: str | None = None) -> None:
    """``SwarmInputError`` when a swarm read from ``source`` (a trajectory file) is larger than ``check_limits`` allows
    (an ``OptionError`` naming ``parameter``, the option that gave the file, if given)."""
    most = MAX_LAUNCHED_ROBOTS if launched else MAX_ROBOTS
    if n > most:
        what = "robots launched as agent processes on one host" if launched else "simulated robots"
        if parameter is not None:
            raise OptionError(parameter, f"{source}: {n} robots, at most {most} ({what})")
        raise SwarmInputError(f"{source}: {n} robots, at most {most} ({what})")


def model_from_flags(model_file: Path | None, flags: Mapping[str, float | None]) -> ModelConfig:
    """``ModelConfig`` of the model file ``model_file`` (or the defaults), overridden by the ``MODEL_FLAGS`` given
    (option dest -> value as typed, degrees for angles; None: not given)."""
    from runtime.models.model_file import load_model  # noqa: PLC0415

    base = load_model(model_file) if model_file is not None else ModelConfig()
    given = {field: to_si(value) for dest, (field, to_si, _) in MODEL_FLAGS.items() if (value := flags.get(dest)) is not None}
    return replace(base, **given)


def selection_from(w_v: float, samples: int, population: int, generations: int, method: str, mc_start: str = "known",
                   mc_emax: str = "mean", genetic: str = "auto") -> SelectionConfig:
    """The anchor search of Eq. 3 weights (``w_v``, ``w_l = 1 - w_v``), the Monte Carlo / genetic budget, the
    Monte Carlo readings (``mc_start``, ``mc_emax``) and where the genetic search runs (``genetic``: ``SelectionConfig``)."""
    from coordinator.selection.genetic import GeneticConfig  # noqa: PLC0415 - scipy, only when a run starts
    from coordinator.selection.selector import SelectionConfig  # noqa: PLC0415

    if not 0.0 <= w_v <= 1.0:
        raise OptionError("w_v", f"must be in [0, 1], got {w_v}")
    if population < 2:
        raise OptionError("population", f"must be >= 2, got {population}")
    if generations < 0:
        raise OptionError("generations", f"must be >= 0, got {generations}")
    return SelectionConfig(w_v=w_v, w_l=1.0 - w_v, samples=samples,
                           genetic=GeneticConfig(population=population, generations=generations), method=method,
                           mc_start=mc_start, mc_emax=mc_emax, genetic_gate=genetic)
