"""Localize robots from a user's own range/bearing observations (format: docs/localize-input.md).

Without a prior the answer is the topology in the local frame of the reference robot
(the lowest-indexed robot that observed someone: origin at its position, x-axis along
its heading). With a prior for every robot the answer is global: the prior is fused
with the observations as a step in which nobody moved.

Real data: robots that cannot be localized (unobserved, or cut off from the rest) are
left out and listed under ``excluded`` unless ``strict``; outliers are resisted by
a Huber loss unless ``robust=False``. When the solver fails (no convergence, singular
information), the robots it names are left out too and the rest is localized.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from runtime.errors import SwarmInputError
from runtime.models.config import ModelConfig
from runtime.models.state import Observations, StepCommands, SwarmEstimate, robot_ids

HUBER_SIGMAS = 3.0


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
    by_id: dict[int, dict] = {}
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


def localize_document(data: Any, cfg: ModelConfig, localizer: str, *, strict: bool, robust: bool) -> dict:
    """The output document for one input document."""
    from coordinator.localization import make_localizer  # noqa: PLC0415 - scipy when localizing, not for --help
    from coordinator.localization.partial import solvable_subset  # noqa: PLC0415

    ids, obs, prior = parse_input(data)
    all_ids, i, j = ids, *obs.indexed(ids)
    if localizer == "paper":
        options = {"huber": HUBER_SIGMAS * math.hypot(cfg.range_sigma_m, cfg.sensing_range_m * cfg.bearing_sigma_rad) if robust else None}
    elif localizer == "joint":
        options = {"huber": HUBER_SIGMAS if robust else None}
    else:  # a registered localizer: its own defaults (the Huber threshold's unit is each localizer's)
        options = {}
    loc = make_localizer(localizer, cfg, **options)

    def solve(keep: np.ndarray):
        sub_obs = obs.select(keep[i] & keep[j])
        if prior is None:
            return loc.topology(all_ids[keep], sub_obs)
        return loc.localize(prior.select(keep), StepCommands.stationary(all_ids[keep]), sub_obs)

    excluded: dict[int, str] = {}
    if strict:
        result = solve(np.ones(len(ids), bool))
    else:
        keep, result, excluded = solvable_subset(solve, ids, obs)
        ids = ids[keep]
    if prior is None:
        topo = result
        robots = [
            {"id": int(r), "x": float(p[0]), "y": float(p[1]), "heading": None if not np.isfinite(h) else float(h), "delta_p": float(dp)}
            for r, p, h, dp in zip(ids, topo.positions, topo.headings, topo.delta_p, strict=True)
        ]
        frame = {"frame": "local", "reference": int(ids[topo.reference])}
    else:
        est = result
        robots = [
            {"id": int(r), "x": float(p[0]), "y": float(p[1]), "heading": float(p[2]), "delta_p": float(dp)}
            for r, p, dp in zip(est.ids, est.poses, est.delta, strict=True)
        ]
        frame = {"frame": "global"}
    return {
        "localizer": localizer,
        **frame,
        "robots": robots,
        "excluded": [{"id": k, "reason": v} for k, v in sorted(excluded.items())],
    }


def localize(source: str | Path | dict, model: ModelConfig | None = None, localizer: str = "paper", *,
             strict: bool = False, robust: bool = True) -> dict:
    """Localize the robots of a JSON file (or its decoded document): the ``swarm localize`` answer
    (frame, poses in m and rad with their covariances, and the robots left out with why)."""
    if isinstance(source, dict):
        data = source
    else:
        try:
            data = json.loads(Path(source).read_text())
        except json.JSONDecodeError as exc:
            raise SwarmInputError(f"{source} is not valid JSON: {exc}") from None
    return localize_document(data, model or ModelConfig(), localizer, strict=strict, robust=robust)
