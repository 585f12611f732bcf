"""Fit the noise model to a lab's robots: a recorded run and a tracker's true poses (``swarm calibrate``; docs/calibration.md).

Reads the executed commands and observation reports of the recording and the true poses at
step ends from the tracker's CSV (``runtime.recording.truth_csv``), fits turn and drive
noise, range and bearing noise, dropout and sensing range by maximum likelihood with
confidence intervals and tests for systematic errors (``runtime.models.noise_fit``), and
writes the model file (TOML) that ``--model FILE`` reads.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast, overload

from inchworm.options import call_keywords
from runtime.errors import OptionError
from runtime.paths import StrPath, coerce_paths


@dataclass
class NoiseCalibration:
    """The fit (``fit``: its JSON, units of the flags of the same names) and the model file written."""

    recording: Path
    truth: Path
    model_file: Path
    fit: dict[str, Any]

    def to_json(self) -> dict[str, Any]:
        return {**self.fit, "recording": str(self.recording), "truth": str(self.truth), "model_file": str(self.model_file)}

    def report(self) -> str:
        """The fitted values, their intervals, the tests and the sample counts, one line each."""
        result = self.fit
        level = f"{100 * result['confidence']:g} %"
        lines = []
        for key in ("turn_sigma_deg", "drive_sigma_frac", "range_sigma_m", "bearing_sigma_deg", "dropout", "sensing_range_m"):
            ci = result["ci"][key]
            interval = "not identified" if ci is None else f"[{_fmt(ci[0])}, {_fmt(ci[1]) if ci[1] is not None else 'not bounded'}]"
            lines.append(f"{key:<18} {_fmt(result[key]):>10}   {level} CI {interval}")
        for name, t in result["systematic"].items():
            verdict = "significant" if t["significant"] else "not significant"
            lines.append(f"{name:<18} {_fmt(t['estimate']):>10}   CI [{_fmt(t['ci'][0])}, {_fmt(t['ci'][1])}], p = {t['p_value']:.3g} ({verdict})")
        s = result["samples"]
        lines.append(f"samples: {s['turns']} turns, {s['drives']} drives, {s['observations']} observations, "
                     f"{s['pairs_in_range']} of {s['pairs']} pairs within the sensing range")
        if result["unidentified"]:
            lines.append(f"not identified (defaults kept in the model file): {', '.join(result['unidentified'])}")
        return "\n".join(lines)


def _fmt(v: float | None) -> str:
    return "-" if v is None else f"{v:.4g}"


@dataclass(frozen=True, kw_only=True)
class CalibrateOptions:
    """Settings of ``calibrate_noise`` (``swarm calibrate``'s flags): the MCAP ``recording``, the tracker CSV ``truth``,
    the model file ``out`` to write (None: the recording's name with ``.model.toml``) and the ``confidence`` level of
    the intervals."""

    recording: StrPath
    truth: StrPath = field(metadata={"metavar": "CSV", "help": "true poses at step ends: robot,step,x,y,heading (m, rad), or "
                                                               "robot,time,x,y,heading (docs/calibration.md)"})
    out: StrPath | None = field(default=None, metadata={"metavar": "FILE",
                                                        "help": "model file to write (TOML; default: the recording's name with .model.toml)"})
    confidence: float = field(default=0.95, metadata={"help": "level of the confidence intervals"})

    def __post_init__(self) -> None:
        coerce_paths(self, "recording", "truth", "out")
        if isinstance(self.confidence, bool) or not isinstance(self.confidence, (int, float)) or not (
                math.isfinite(self.confidence) and 0.5 <= self.confidence < 1):
            raise OptionError("confidence", f"must be in [0.5, 1), got {self.confidence}", self)

    @property
    def model_file(self) -> Path:
        """The model file written: ``out``, or the recording's name with ``.model.toml``."""
        return Path(self.out) if self.out is not None else Path(self.recording).with_suffix(".model.toml")


@overload
def calibrate_noise(options: CalibrateOptions, /) -> NoiseCalibration: ...
@overload
def calibrate_noise(recording: StrPath, truth: StrPath, out: StrPath | None = None, confidence: float = ..., /) -> NoiseCalibration: ...
def calibrate_noise(options: CalibrateOptions | StrPath, /, *args: Any, **keywords: Any) -> NoiseCalibration:
    """Fit the noise of the recording against the tracker CSV ``truth``; write the model file ``out``
    (default: the recording's name with ``.model.toml``). ``calibrate_noise(CalibrateOptions(recording=r, truth=t))``
    is ``calibrate_noise(r, t)``."""
    from runtime.models.noise_fit import fit_noise  # noqa: PLC0415 - scipy only when fitting
    from runtime.recording.run_log import load_run_log  # noqa: PLC0415
    from runtime.recording.truth_csv import read_truth_csv  # noqa: PLC0415

    o = _options_of(options, args, keywords)
    recording, truth, out = Path(o.recording), Path(o.truth), o.model_file
    log = load_run_log(recording)
    truths = read_truth_csv(truth, log.ids, log.step_end_times())
    fit = fit_noise(log.commands, log.observations, truths, o.confidence)
    if fit.turn is None and fit.range is None:
        raise OptionError("truth", f"{truth}: no step of the recording has true poses for its robots (steps 0, 1, ... of robots {log.ids})", o)
    out.write_text(fit.to_toml(f"noise model of {recording.name} fitted by swarm calibrate (truth {truth.name})"), encoding="utf-8")
    return NoiseCalibration(recording, truth, out, fit.to_json())


def _options_of(options: CalibrateOptions | StrPath, args: tuple[Any, ...], keywords: dict[str, Any]) -> CalibrateOptions:
    """``calibrate_noise``'s options: the ``CalibrateOptions`` given, or those of the recording and the ``truth``,
    ``out`` and ``confidence`` (positional or keywords)."""
    given = call_keywords("calibrate_noise", CalibrateOptions, options, "recording", ("truth", "out", "confidence"), args, keywords)
    return cast(CalibrateOptions, options) if given is None else CalibrateOptions(**given)
