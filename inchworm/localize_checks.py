"""Checks of measured range/bearing rows for ``swarm localize`` (docs/localize-input.md, "Checks").

* Duplicated rows (the same four numbers twice, a logging artefact) are used once.
* Ranges beyond the sensing range (``RANGE_SIGMAS`` range sigmas of slack) are named: the sensing
  range sets the paper localizer's outlier threshold and the delta_p floors, so a wrong one misleads both.
* Every row's whitened residual at the solution, (predicted - measured) / sigma for the range and
  the bearing (the joint localizer's terms, ``range_bearing.observation_residuals``), and a row is a
  suspect when r_range^2 + r_bearing^2 exceeds ``SUSPECT_CHI2``, the chi-square of 2 degrees of
  freedom at the 3-sigma probability (99.73 %).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from runtime.models.config import ModelConfig
from runtime.models.state import Observations

RANGE_SIGMAS = 3.0  # slack beyond the sensing range, in range sigmas, before a range is named
SUSPECT_CHI2 = -2.0 * math.log(1.0 - 0.9973)  # 11.83: chi-square of 2 dof at the 3-sigma probability
LISTED_ROWS = 20  # rows named in one warning line before "..."


def duplicate_rows(obs: Observations) -> np.ndarray:
    """(m,) index of the first identical row for every row repeating an earlier one, -1 elsewhere."""
    table = np.column_stack([obs.observer, obs.observed, obs.range_m, obs.bearing_rad])
    _, first, inverse = np.unique(table, axis=0, return_index=True, return_inverse=True)
    first_of = first[inverse.ravel()]
    return np.where(first_of < np.arange(len(obs)), first_of, -1)


def beyond_sensing_range(obs: Observations, cfg: ModelConfig) -> np.ndarray:
    """Rows whose range exceeds the sensing range by more than ``RANGE_SIGMAS`` range sigmas."""
    return np.flatnonzero(obs.range_m > cfg.sensing_range_m + RANGE_SIGMAS * cfg.range_sigma_m)


def whitened_residuals(poses: np.ndarray, i: np.ndarray, j: np.ndarray, obs: Observations, cfg: ModelConfig) -> np.ndarray:
    """(m, 2) whitened (range, bearing) residuals of observations i -> j (indices into ``poses`` (n, 3))."""
    from coordinator.localization.range_bearing import bearing_weights, observation_residuals, sensor_sigmas  # noqa: PLC0415 - scipy

    d = poses[j, :2] - poses[i, :2]
    r_range, r_bearing, _ = observation_residuals(d[:, 0], d[:, 1], obs.range_m, 1.0 / sensor_sigmas(cfg)[0],
                                                  bearing_weights(obs.range_m, cfg), direction=poses[i, 2] + obs.bearing_rad)
    return np.column_stack([r_range, r_bearing])


def row_list(rows: np.ndarray) -> str:
    """'3, 7, 9' (at most ``LISTED_ROWS``, then '... (N in all)')."""
    shown = ", ".join(str(int(r)) for r in rows[:LISTED_ROWS])
    return shown if len(rows) <= LISTED_ROWS else f"{shown}, ... ({len(rows)} in all)"


def observation_checks(obs: Observations, used: np.ndarray, poses: np.ndarray, solved: np.ndarray, cfg: ModelConfig) ->dict[str, Any]:
    """The JSON keys of the checks: ``observations`` (per row: residuals, suspect, used), ``suspects``,
    ``suspect_chi2``, ``duplicates``, ``beyond_sensing_range``, ``sensing_range_m`` and ``warnings`` (one line each).

    ``used`` (m,): rows the localizer used; ``poses`` (k, 3) the solution of robots ``solved`` (k,) (ids),
    headings NaN where unknown (no row of a used observer has one).
    """
    where = {int(r): k for k, r in enumerate(solved)}
    rows = np.flatnonzero(used)
    residuals = np.full((len(obs), 2), np.nan)
    if rows.size:
        i = np.array([where[int(r)] for r in obs.observer[rows]])
        j = np.array([where[int(r)] for r in obs.observed[rows]])
        residuals[rows] = whitened_residuals(poses, i, j, obs.select(used), cfg)
    chi2 = np.sum(residuals**2, axis=1)
    suspect = used & (chi2 > SUSPECT_CHI2)
    duplicate = duplicate_rows(obs)
    dup_rows, far = np.flatnonzero(duplicate >= 0), beyond_sensing_range(obs, cfg)
    warnings = []
    if dup_rows.size:
        warnings.append(f"duplicated observation rows {row_list(dup_rows)} (the same as an earlier row) are used once")
    if far.size:
        warnings.append(f"observation rows {row_list(far)} have ranges beyond the sensing range {cfg.sensing_range_m:g} m "
                        f"(+{RANGE_SIGMAS:g} range sigmas): set --sensing-range (or --model FILE) to your sensor's")
    if suspect.any():
        warnings.append(f"suspect observation rows {row_list(np.flatnonzero(suspect))} (whitened residual chi-square > "
                        f"{SUSPECT_CHI2:.2f}): a wrong robot id, a reflection, or sigmas set too small")

    def number(x: float) -> float | None:
        return float(x) if math.isfinite(x) else None

    return {
        "observations": [
            {"row": k, "observer": int(obs.observer[k]), "observed": int(obs.observed[k]), "used": bool(used[k]),
             "range_residual": number(residuals[k, 0]), "bearing_residual": number(residuals[k, 1]), "suspect": bool(suspect[k])}
            for k in range(len(obs))
        ],
        "suspects": np.flatnonzero(suspect).tolist(),
        "suspect_chi2": round(SUSPECT_CHI2, 4),
        "duplicates": dup_rows.tolist(),
        "beyond_sensing_range": far.tolist(),
        "sensing_range_m": cfg.sensing_range_m,
        "warnings": warnings,
    }
