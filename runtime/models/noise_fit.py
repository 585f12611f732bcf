"""Maximum-likelihood fit of the motion and sensing model to a lab's robots (docs/calibration.md).

Input: the executed commands and the observation reports of a run by (robot, global step),
and the true poses at step ends from an external tracker. Each executed command of robot r
at step s, with true poses p0 (end of step s - 1) and p1 (end of step s), gives

* a turn residual  wrap(h1 - h0 - turn)           (model: N(0, turn sigma)),
* a drive ratio    (p1 - p0) . u(h1) / drive        (model: 1 + N(0, drive sigma fraction)),

and each observation report of robot i at step s, with every robot j present at s
(reporting at s and tracked at s), gives the true distance d_ij and, for the robots it
observed, a range residual and a wrapped bearing residual (model: N(0, range sigma),
N(0, bearing sigma)). The Gaussian parameters have closed-form maximum-likelihood
estimates; the confidence intervals are exact (chi-square for a sigma, Student t for a
mean). A systematic error (a turn bias, a drive scale != 1, a range bias, a bearing
offset) is the alternative of a likelihood-ratio test (chi-square, 1 degree of freedom):
when it is significant the fitted sigma is the one about the fitted bias (the noise left
once the bias is corrected, e.g. by the gateway's per-robot calibration), else the one
about zero.

Sensing range and dropout come from the pairs: the range is estimated as the largest true
distance at which an observation was made (an observation proves the range is at least
that; censored data say nothing finer below it), the dropout as the share of pairs within
it that were not observed (Clopper-Pearson interval). Above the estimate the range is
bounded by the unobserved pairs: if the range reached the k-th unobserved distance, k
pairs within range would all have been dropped, probability <= dropout^k; the upper bound
is the first such distance with probability <= 1 - confidence. Without pairs beyond the
estimate the range is not identified from above (upper bound None).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from scipy import stats

from runtime.models.config import ModelConfig
from runtime.models.geometry import wrap_angle
from runtime.models.model_file import model_toml

CONFIDENCE = 0.95
ALPHA_SIGNIFICANT = 0.05  # a systematic error is reported significant at p below this


@dataclass(frozen=True)
class GaussFit:
    """Samples x ~ N(mu, sigma): the fit with mu fixed at ``null_mean`` and with mu free, and their test."""

    n: int
    mean: float
    mean_ci: tuple[float, float]
    sigma_null: float  # about null_mean
    sigma_null_ci: tuple[float, float]
    sigma_free: float  # about the fitted mean
    sigma_free_ci: tuple[float, float]
    lr: float  # 2 (log L_free - log L_null)
    p_value: float

    @property
    def significant(self) -> bool:
        return self.p_value < ALPHA_SIGNIFICANT

    @property
    def sigma(self) -> float:
        """The sigma of the model: about the bias when it is significant, else about the null."""
        return self.sigma_free if self.significant else self.sigma_null

    @property
    def sigma_ci(self) -> tuple[float, float]:
        return self.sigma_free_ci if self.significant else self.sigma_null_ci


def _sigma_ci(ss: float, dof: int, confidence: float) -> tuple[float, float]:
    a = (1 - confidence) / 2
    return math.sqrt(ss / stats.chi2.ppf(1 - a, dof)), math.sqrt(ss / stats.chi2.ppf(a, dof))


def fit_gauss(x: np.ndarray, null_mean: float, confidence: float = CONFIDENCE) -> GaussFit | None:
    """The ``GaussFit`` of samples ``x`` (None with fewer than 3)."""
    x = np.asarray(x, dtype=float)
    n = len(x)
    if n < 3:
        return None
    mean = float(x.mean())
    ss_null = float(np.sum((x - null_mean) ** 2))
    ss_free = float(np.sum((x - mean) ** 2))
    tiny = np.finfo(float).tiny
    lr = float(n * math.log(max(ss_null, tiny) / max(ss_free, tiny)))
    half = stats.t.ppf(1 - (1 - confidence) / 2, n - 1) * math.sqrt(ss_free / (n - 1) / n)
    return GaussFit(n=n, mean=mean, mean_ci=(mean - half, mean + half), sigma_null=math.sqrt(ss_null / n),
                    sigma_null_ci=_sigma_ci(ss_null, n, confidence), sigma_free=math.sqrt(ss_free / n),
                    sigma_free_ci=_sigma_ci(ss_free, n - 1, confidence), lr=lr, p_value=float(stats.chi2.sf(lr, 1)))


@dataclass(frozen=True)
class RangeFit:
    """Sensing range and dropout from the pairs (robot, robot present at a step) and whether each was observed."""

    pairs: int
    in_range: int
    observed: int
    sensing_range_m: float
    sensing_range_ci: tuple[float, float | None]
    dropout: float
    dropout_ci: tuple[float, float]


def fit_range(distances: np.ndarray, observed: np.ndarray, confidence: float = CONFIDENCE) -> RangeFit | None:
    """The ``RangeFit`` of the true pair distances ``distances`` and the mask ``observed`` (None without observations)."""
    distances, observed = np.asarray(distances, dtype=float), np.asarray(observed, dtype=bool)
    if not observed.any():
        return None
    r_hat = float(distances[observed].max())
    within = distances <= r_hat
    k, n = int(observed[within].sum()), int(within.sum())
    dropped = n - k
    a = (1 - confidence) / 2
    low = 0.0 if dropped == 0 else float(stats.beta.ppf(a, dropped, k + 1))
    high = 1.0 if dropped == n else float(stats.beta.ppf(1 - a, dropped + 1, k))
    beyond = np.sort(distances[~observed & (distances > r_hat)])
    upper = None
    if len(beyond):
        # smallest k with high^k <= 1 - confidence: the range is below the k-th unobserved distance beyond r_hat
        need = 1 if high <= 0 else (math.inf if high >= 1 else math.ceil(math.log(1 - confidence) / math.log(high)))
        upper = float(beyond[int(need) - 1]) if need <= len(beyond) else None
    return RangeFit(pairs=len(distances), in_range=n, observed=k, sensing_range_m=r_hat, sensing_range_ci=(r_hat, upper),
                    dropout=dropped / n, dropout_ci=(low, high))


@dataclass(frozen=True)
class NoiseSamples:
    """The residuals a run gives (SI units): see the module docstring."""

    turn: np.ndarray  # rad, one per executed command that moved
    drive_ratio: np.ndarray  # one per executed command with a drive > 0
    range_residual: np.ndarray  # m, one per observation of a tracked robot
    bearing_residual: np.ndarray  # rad
    pair_distance: np.ndarray  # m, one per (observer, robot present) pair
    pair_observed: np.ndarray  # bool, parallel to pair_distance


def noise_samples(commands: Mapping[tuple[int, int], tuple[float, float]],
                  observations: Mapping[tuple[int, int], tuple[np.ndarray, np.ndarray, np.ndarray]],
                  truths: Mapping[tuple[int, int], np.ndarray]) -> NoiseSamples:
    """The residuals of executed ``commands`` and ``observations`` against the true poses ``truths``, by (robot, step)."""
    moves = [(truths[(r, s - 1)], truths[(r, s)], turn, drive) for (r, s), (turn, drive) in sorted(commands.items())
             if (turn != 0.0 or drive != 0.0) and (r, s - 1) in truths and (r, s) in truths]
    if moves:
        p0, p1 = np.array([m[0] for m in moves]), np.array([m[1] for m in moves])
        cmd = np.array([(m[2], m[3]) for m in moves])
    else:
        p0 = p1 = np.zeros((0, 3))
        cmd = np.zeros((0, 2))
    turn = wrap_angle(p1[:, 2] - p0[:, 2] - cmd[:, 0])
    driven = cmd[:, 1] > 0
    along = np.einsum("ij,ij->i", p1[:, :2] - p0[:, :2], np.stack([np.cos(p1[:, 2]), np.sin(p1[:, 2])], axis=1))
    ratio = along[driven] / cmd[driven, 1]

    present: dict[int, list[int]] = {}
    for (r, s) in observations:
        if (r, s) in truths:
            present.setdefault(s, []).append(r)
    rng_res, brg_res, dist, seen = [], [], [], []
    for (i, s), (ids, ranges, bearings) in sorted(observations.items()):
        if (i, s) not in truths:
            continue
        others = np.array(sorted(j for j in present[s] if j != i), dtype=np.int64)
        if not len(others):
            continue
        me = truths[(i, s)]
        pos = np.array([truths[(int(j), s)][:2] for j in others])
        d = pos - me[:2]
        true_range = np.hypot(d[:, 0], d[:, 1])
        true_bearing = wrap_angle(np.arctan2(d[:, 1], d[:, 0]) - me[2])
        ids = np.asarray(ids, dtype=np.int64)
        tracked = np.isin(ids, others)
        index = np.searchsorted(others, ids[tracked])
        rng_res.append(np.asarray(ranges, dtype=float)[tracked] - true_range[index])
        brg_res.append(wrap_angle(np.asarray(bearings, dtype=float)[tracked] - true_bearing[index]))
        mask = np.zeros(len(others), dtype=bool)
        mask[index] = True
        dist.append(true_range)
        seen.append(mask)

    def cat(parts: list[np.ndarray], dtype: type = float) -> np.ndarray:
        return np.concatenate(parts) if parts else np.zeros(0, dtype=dtype)

    return NoiseSamples(turn=turn, drive_ratio=ratio, range_residual=cat(rng_res), bearing_residual=cat(brg_res),
                        pair_distance=cat(dist), pair_observed=cat(seen, bool))


def _ci(pair: tuple[float, float | None], scale: float = 1.0) -> list[float | None]:
    return [None if v is None else v * scale for v in pair]


@dataclass(frozen=True)
class NoiseFit:
    """The fitted model with its confidence intervals and the tests of systematic errors."""

    turn: GaussFit | None
    drive: GaussFit | None
    range: GaussFit | None
    bearing: GaussFit | None
    pairs: RangeFit | None
    confidence: float = CONFIDENCE
    base: ModelConfig = field(default_factory=ModelConfig)

    def model(self) -> ModelConfig:
        """The fitted ``ModelConfig`` (parameters the data do not identify keep ``base``'s values)."""
        changes = {}
        if self.turn is not None:
            changes["turn_sigma_rad"] = self.turn.sigma
        if self.drive is not None:
            changes["drive_sigma_frac"] = self.drive.sigma
        if self.range is not None:
            changes["range_sigma_m"] = self.range.sigma
        if self.bearing is not None:
            changes["bearing_sigma_rad"] = self.bearing.sigma
        if self.pairs is not None:
            changes["sensing_range_m"] = self.pairs.sensing_range_m
            changes["dropout_prob"] = min(self.pairs.dropout, 0.999)
        return replace(self.base, **changes)

    def unidentified(self) -> list[str]:
        """Keys (model file names) the data said nothing about (fewer than 3 samples)."""
        out = [name for name, fit in (("turn_sigma_deg", self.turn), ("drive_sigma_frac", self.drive),
                                      ("range_sigma_m", self.range), ("bearing_sigma_deg", self.bearing)) if fit is None]
        return out + (["dropout", "sensing_range_m"] if self.pairs is None else [])

    def _systematic(self) -> dict[str, dict[str, Any]]:
        out = {}
        for name, fit, scale in (("turn_bias_deg", self.turn, math.degrees(1.0)), ("drive_scale", self.drive, 1.0),
                                 ("range_bias_m", self.range, 1.0), ("bearing_bias_deg", self.bearing, math.degrees(1.0))):
            if fit is not None:
                out[name] = {"estimate": fit.mean * scale, "ci": _ci(fit.mean_ci, scale), "lr": fit.lr,
                             "p_value": fit.p_value, "significant": fit.significant}
        return out

    def to_json(self) -> dict[str, Any]:
        """Plain JSON: the model values in the flags' units (degrees for angles), CIs, tests and sample counts."""
        deg = math.degrees(1.0)

        def sig(fit: GaussFit | None, scale: float) -> tuple[float | None, list[float | None] | None]:
            return (None, None) if fit is None else (fit.sigma * scale, _ci(fit.sigma_ci, scale))

        out: dict[str, Any] = {}
        ci: dict[str, Any] = {}
        for key, fit, scale in (("turn_sigma_deg", self.turn, deg), ("drive_sigma_frac", self.drive, 1.0),
                                ("range_sigma_m", self.range, 1.0), ("bearing_sigma_deg", self.bearing, deg)):
            out[key], ci[key] = sig(fit, scale)
        p = self.pairs
        out["dropout"], ci["dropout"] = (None, None) if p is None else (p.dropout, list(p.dropout_ci))
        out["sensing_range_m"], ci["sensing_range_m"] = (None, None) if p is None else (p.sensing_range_m, list(p.sensing_range_ci))
        out["ci"] = ci
        out["confidence"] = self.confidence
        out["systematic"] = self._systematic()
        out["samples"] = {"turns": 0 if self.turn is None else self.turn.n, "drives": 0 if self.drive is None else self.drive.n,
                          "observations": 0 if self.range is None else self.range.n,
                          "pairs": 0 if p is None else p.pairs, "pairs_in_range": 0 if p is None else p.in_range}
        out["unidentified"] = self.unidentified()
        return out

    def to_toml(self, header: str = "") -> str:
        """The model file (``runtime.models.model_file``) of the fit: ``[model]`` and the ``[fit.*]`` tables."""
        j = self.to_json()
        keys = ("turn_sigma_deg", "drive_sigma_frac", "range_sigma_m", "bearing_sigma_deg", "dropout", "sensing_range_m")
        fit = {"ci": {k: [math.inf if v is None else v for v in j["ci"][k]] for k in keys if j["ci"][k] is not None},
               "samples": j["samples"]}
        for name, test in j["systematic"].items():
            fit[name] = {"estimate": test["estimate"], "ci": test["ci"], "p_value": test["p_value"], "significant": test["significant"]}
        return model_toml(self.model(), fit, header)


def fit_noise(commands: Mapping[tuple[int, int], tuple[float, float]],
              observations: Mapping[tuple[int, int], tuple[np.ndarray, np.ndarray, np.ndarray]],
              truths: Mapping[tuple[int, int], np.ndarray], confidence: float = CONFIDENCE,
              base: ModelConfig = ModelConfig()) -> NoiseFit:
    """Fit every parameter of the model to a run (see the module docstring)."""
    s = noise_samples(commands, observations, truths)
    return NoiseFit(turn=fit_gauss(s.turn, 0.0, confidence), drive=fit_gauss(s.drive_ratio, 1.0, confidence),
                    range=fit_gauss(s.range_residual, 0.0, confidence), bearing=fit_gauss(s.bearing_residual, 0.0, confidence),
                    pairs=fit_range(s.pair_distance, s.pair_observed, confidence), confidence=confidence, base=base)
