"""Localize robots from a user's own range/bearing observations (format: docs/localize-input.md).

Without a prior the answer is the topology in the local frame of the reference robot
(the lowest-indexed robot that observed someone: origin at its position, x-axis along
its heading). With a prior for every robot the answer is global: the prior is fused
with the observations as a step in which nobody moved.

Real data: a robot is localized when the observations in either direction (and, for the
joint localizer, the prior's headings) fix it (``graph.localizable_subset``); the others
are left out and listed under ``excluded`` unless ``strict``. Outliers are resisted by
a Huber loss unless ``robust=False``. When the solver fails (no convergence, singular
information), the robots it names are left out too and the rest is localized.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast, overload

import numpy as np

from inchworm.localize_checks import duplicate_rows, observation_checks
from inchworm.options import call_keywords
from runtime.errors import LocalizationError, OptionError, SwarmInputError
from runtime.models.config import ModelConfig
from runtime.models.state import Observations, StepCommands, SwarmEstimate, robot_ids
from runtime.paths import StrPath

if TYPE_CHECKING:
    from coordinator.localization.topology import Topology

HUBER_SIGMAS = 3.0


@dataclass(frozen=True)
class LocalizedRobot:
    """A robot's pose: ``x``, ``y`` (m) and ``heading`` (rad; None when nothing fixes it: it observed nobody), the
    position uncertainty ``delta_p`` (m) and the heading's ``sigma_heading`` (rad; None when unknown)."""

    id: int
    x: float
    y: float
    heading: float | None
    delta_p: float
    sigma_heading: float | None

    def to_json(self) -> dict[str, Any]:
        return {"id": self.id, "x": self.x, "y": self.y, "heading": self.heading, "delta_p": self.delta_p,
                "sigma_heading": self.sigma_heading}


@dataclass(frozen=True)
class LocalizeResult:
    """What ``localize`` found: the robots localized in ``frame`` (``"local"``: the ``reference`` robot's frame, no
    prior; ``"global"``: the prior's), the robots left out with why (``excluded``: id -> reason) and the checks of
    the observation rows (``checks``: ``observations``, ``suspects``, ``warnings``, ...; docs/localize-input.md).
    ``to_json()`` is the document ``swarm localize`` prints."""

    localizer: str
    frame: str
    reference: int | None
    robots: tuple[LocalizedRobot, ...]
    excluded: dict[int, str]
    checks: dict[str, Any]

    @property
    def warnings(self) -> list[str]:
        """The checks' warnings (duplicated rows, ranges beyond the sensing range, suspects), one line each."""
        return list(self.checks["warnings"])

    def robot(self, robot_id: int) -> LocalizedRobot:
        """The pose of robot ``robot_id`` (``SwarmInputError`` if it was not localized)."""
        for robot in self.robots:
            if robot.id == robot_id:
                return robot
        raise SwarmInputError(f"robot {robot_id} was not localized: {self.excluded.get(robot_id, 'not in the input')}")

    def to_json(self) -> dict[str, Any]:
        frame: dict[str, Any] = {"frame": self.frame} if self.reference is None else {"frame": self.frame, "reference": self.reference}
        return {"localizer": self.localizer, **frame, "robots": [r.to_json() for r in self.robots],
                "excluded": [{"id": k, "reason": v} for k, v in sorted(self.excluded.items())], **self.checks}


def _number(value: Any, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise SwarmInputError(f"{where}: expected a finite number, got {value!r}")
    return float(value)


def _robot_id(value: Any, where: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise SwarmInputError(f"{where}: robot ids are integers >= 0, got {value!r}")
    return value


def parse_input(data: Any) -> tuple[np.ndarray, Observations, SwarmEstimate | None]:
    """(robot ids, observations, prior or None) from the decoded JSON document."""
    if not isinstance(data, dict):
        raise SwarmInputError("input must be a JSON object with 'robots' and 'observations'")
    robots = data.get("robots")
    if not isinstance(robots, list) or not robots:
        raise SwarmInputError("'robots' must be a non-empty list of robot ids")
    ids = robot_ids(np.array([_robot_id(r, f"robots[{k}]") for k, r in enumerate(robots)], dtype=np.int64))
    rows = data.get("observations")
    if not isinstance(rows, list):
        raise SwarmInputError("'observations' must be a list of [observer, observed, range_m, bearing_rad] rows")
    table = []
    for k, row in enumerate(rows):
        if not isinstance(row, list) or len(row) != 4:
            raise SwarmInputError(f"observations[{k}]: expected [observer, observed, range_m, bearing_rad], got {row!r}")
        table.append([_robot_id(row[0], f"observations[{k}][0]"), _robot_id(row[1], f"observations[{k}][1]"),
                      _number(row[2], f"observations[{k}][2] (range_m)"), _number(row[3], f"observations[{k}][3] (bearing_rad)")])
    obs = Observations.from_rows(np.array(table, dtype=float).reshape(-1, 4))
    obs.indexed(ids)  # unknown ids raise, naming them
    return ids, obs, _parse_prior(data.get("prior"), ids)


def _parse_prior(prior: Any, ids: np.ndarray) -> SwarmEstimate | None:
    if prior is None:
        return None
    if not isinstance(prior, list):
        raise SwarmInputError("'prior' must be a list of {id, x, y, heading, delta, sigma_heading} objects")
    by_id: dict[int, dict[str, Any]] = {}
    for k, entry in enumerate(prior):
        if not isinstance(entry, dict):
            raise SwarmInputError(f"prior[{k}]: expected an object, got {entry!r}")
        by_id[_robot_id(entry.get("id"), f"prior[{k}].id")] = entry
    missing = sorted(set(ids.tolist()) - set(by_id))
    unknown = sorted(set(by_id) - set(ids.tolist()))
    if missing or unknown:
        raise SwarmInputError(f"prior must cover exactly the robots: missing {missing}, unknown {unknown}")
    fields = ("x", "y", "heading", "delta", "sigma_heading")
    values = np.array([[_number(by_id[int(r)].get(f), f"prior id {r}: '{f}'") for f in fields] for r in ids])
    if np.any(values[:, 3:] < 0):
        raise SwarmInputError("prior uncertainties (delta, sigma_heading) must be >= 0")
    return SwarmEstimate.isotropic(ids, values[:, :3], values[:, 3], values[:, 4])


def _fixed_headings(prior: SwarmEstimate | None, localizer: str) -> bool:
    """Whether the prior fixes every heading for the localizer: the joint one solves the prior with the
    observations; the paper's topology (and a plugin's, as far as we know) ignores it."""
    return prior is not None and localizer == "joint"


def _left_out_error(excluded: dict[int, str]) -> LocalizationError:
    """``--strict``: the error naming the robots left out, under the reason most of them share."""
    reasons = list(excluded.values())
    reason = max(set(reasons), key=lambda r: (reasons.count(r), r))
    others = sorted({f"{r} {k}" for k, r in excluded.items() if r != reason})
    return LocalizationError(reason, [k for k, r in excluded.items() if r == reason],
                             "cannot be localized" + (f"; also {', '.join(others)}" if others else ""))


def localize_document(data: Any, cfg: ModelConfig, localizer: str, *, strict: bool, robust: bool) -> LocalizeResult:
    """The answer for one input document (already decoded)."""
    from coordinator.localization import make_localizer  # noqa: PLC0415 - scipy when localizing, not for --help
    from coordinator.localization.graph import localizable_subset  # noqa: PLC0415
    from coordinator.localization.partial import solvable_subset  # noqa: PLC0415

    ids, obs, prior = parse_input(data)
    unique = duplicate_rows(obs) < 0
    all_ids, i, j = ids, *obs.indexed(ids)
    if localizer == "paper":
        options = {"huber": HUBER_SIGMAS * math.hypot(cfg.range_sigma_m, cfg.sensing_range_m * cfg.bearing_sigma_rad) if robust else None}
    elif localizer == "joint":
        options = {"huber": HUBER_SIGMAS if robust else None}
    else:  # a registered localizer: its own defaults (the Huber threshold's unit is each localizer's)
        options = {}
    loc = make_localizer(localizer, cfg, **options)
    headings_known = _fixed_headings(prior, localizer)

    def subset(sub_ids: np.ndarray, observer: np.ndarray, observed: np.ndarray) -> tuple[np.ndarray, dict[int, str]]:
        return localizable_subset(sub_ids, observer, observed, headings_known=headings_known)

    def solve(keep: np.ndarray) -> Topology | SwarmEstimate:
        sub_obs = obs.select(keep[i] & keep[j] & unique)
        if prior is None:
            return loc.topology(all_ids[keep], sub_obs)
        return loc.localize(prior.select(keep), StepCommands.stationary(all_ids[keep]), sub_obs)

    unique_obs = obs.select(unique)
    if strict:
        keep, excluded = subset(ids, *unique_obs.indexed(ids))
        if excluded:
            raise _left_out_error(excluded)
        result = solve(keep)
    else:
        keep, result, excluded = solvable_subset(solve, ids, unique_obs, subset=subset)
    ids = ids[keep]
    if prior is None:
        topo = cast("Topology", result)  # no prior: ``solve`` gave the topology
        poses = np.column_stack([topo.positions, topo.headings])
        robots = tuple(LocalizedRobot(int(r), float(p[0]), float(p[1]), _finite(p[2]), float(dp), _finite(sh))
                       for r, p, dp, sh in zip(ids, poses, topo.delta_p, topo.heading_sigma, strict=True))
        frame, reference = "local", int(ids[topo.reference])
    else:
        est = cast(SwarmEstimate, result)
        poses = est.poses
        robots = tuple(LocalizedRobot(int(r), float(p[0]), float(p[1]), float(p[2]), float(dp), float(np.sqrt(max(c[2, 2], 0.0))))
                       for r, p, dp, c in zip(est.ids, est.poses, est.delta, est.cov, strict=True))
        frame, reference = "global", None
    used = keep[i] & keep[j] & unique
    return LocalizeResult(localizer, frame, reference, robots, dict(excluded), observation_checks(obs, used, poses, ids, cfg))


def _finite(x: float) -> float | None:
    """JSON has no NaN or infinity: an unknown heading or its infinite sigma is null."""
    return float(x) if np.isfinite(x) else None


@dataclass(frozen=True, kw_only=True)
class LocalizeOptions:
    """Settings of ``localize`` (``swarm localize``'s flags): the JSON file or its decoded document ``source``, the noise
    ``model``, the ``localizer``'s registered name, ``strict`` (fail rather than leave out robots) and ``robust`` (the
    Huber loss against outliers)."""

    source: StrPath | dict[str, Any]
    model: ModelConfig = field(default_factory=ModelConfig)
    localizer: str = "paper"
    strict: bool = field(default=False, metadata={"help": "fail instead of leaving out robots that cannot be localized"})
    robust: bool = field(default=True, metadata={"flag": "--no-robust", "help": "plain least squares (no Huber loss against outliers)"})

    def __post_init__(self) -> None:
        if isinstance(self.source, (str, os.PathLike)):
            object.__setattr__(self, "source", Path(self.source))
        elif not isinstance(self.source, dict):
            raise OptionError("source", f"must be a JSON file's path or its decoded document (a dict), got {self.source!r}", self)
        if not isinstance(self.model, ModelConfig):
            raise OptionError("model", f"must be a ModelConfig, got {self.model!r}", self)
        if not isinstance(self.localizer, str) or not self.localizer:
            raise OptionError("localizer", f"must be a registered localizer's name, got {self.localizer!r}", self)
        for name in ("strict", "robust"):
            if not isinstance(getattr(self, name), bool):
                raise OptionError(name, f"must be True or False, got {getattr(self, name)!r}", self)


@overload
def localize(options: LocalizeOptions, /) -> LocalizeResult: ...
@overload
def localize(source: StrPath | dict[str, Any], model: ModelConfig | None = None, localizer: str = ..., /, *,
             strict: bool = ..., robust: bool = ...) -> LocalizeResult: ...
def localize(options: LocalizeOptions | StrPath | dict[str, Any], /, *args: Any, **keywords: Any) -> LocalizeResult:
    """Localize the robots of a JSON file (or its decoded document): the ``swarm localize`` answer
    (frame, poses in m and rad with their uncertainties, the robots left out with why, and the checks of
    the rows: residuals, suspects, duplicates, ranges beyond the sensing range, ``localize_checks``).
    ``localize(LocalizeOptions(source=file, localizer="joint"))`` is ``localize(file, None, "joint")``
    (``model=None``: the default model)."""
    o = _options_of(options, args, keywords)
    if isinstance(o.source, dict):
        data = o.source
    else:
        try:
            data = json.loads(Path(o.source).read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError) as exc:
            raise SwarmInputError(f"{o.source}: cannot read it: {getattr(exc, 'strerror', None) or exc}") from None
        except json.JSONDecodeError as exc:
            raise SwarmInputError(f"{o.source} is not valid JSON: {exc}") from None
    return localize_document(data, o.model, o.localizer, strict=o.strict, robust=o.robust)


def _options_of(options: LocalizeOptions | StrPath | dict[str, Any], args: tuple[Any, ...], keywords: dict[str, Any]) -> LocalizeOptions:
    """``localize``'s options: the ``LocalizeOptions`` given, or those of the source, ``model`` and ``localizer``
    (positional or keywords) and the keywords (``model=None``: the default model)."""
    given = call_keywords("localize", LocalizeOptions, options, "source", ("model", "localizer"), args, keywords)
    if given is None:
        return cast(LocalizeOptions, options)
    return LocalizeOptions(**{k: v for k, v in given.items() if v is not None or k != "model"})
