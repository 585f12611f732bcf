"""``swarm calibrate RUN.mcap --truth TRUTH.csv``: fit the noise model to a lab's robots (docs/calibration.md).

    swarm calibrate recordings/lab.mcap --truth tracker.csv [--out lab-model.toml] [--json]

Reads the executed commands and observation reports of the recording and the true poses
at step ends from the tracker's CSV (``runtime.recording.truth_csv``), fits turn and drive
noise, range and bearing noise, dropout and sensing range by maximum likelihood with
confidence intervals and tests for systematic errors (``runtime.models.noise_fit``), prints
them and writes the model file (TOML) that ``--model FILE`` reads. The ``--json`` last line
holds ``turn_sigma_deg``, ``drive_sigma_frac``, ``range_sigma_m``, ``bearing_sigma_deg``,
``dropout``, ``sensing_range_m`` (the units of the flags of the same names), ``ci``,
``systematic``, ``samples``, ``unidentified`` and ``model_file``.
Exit status 0, 2 on bad input (unreadable recording, bad CSV row, nothing to fit).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from swarm_cli.options import add_json_option, print_json


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("calibrate", help="fit the noise model (motion, sensing) to a recorded run and a tracker's true poses")
    p.add_argument("file", type=Path, help="MCAP recording of the run (swarm coordinator / swarm record)")
    p.add_argument("--truth", type=Path, required=True, metavar="CSV",
                   help="true poses at step ends: robot,step,x,y,heading (m, rad), or robot,time,x,y,heading (docs/calibration.md)")
    p.add_argument("--out", type=Path, default=None, metavar="FILE",
                   help="model file to write (TOML; default: the recording's name with .model.toml)")
    p.add_argument("--confidence", type=float, default=0.95, help="level of the confidence intervals (default 0.95)")
    add_json_option(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from runtime.errors import SwarmInputError  # noqa: PLC0415 - scipy and numpy only when a command runs
    from runtime.models.noise_fit import fit_noise  # noqa: PLC0415
    from runtime.recording.run_log import load_run_log  # noqa: PLC0415
    from runtime.recording.truth_csv import read_truth_csv  # noqa: PLC0415

    if not 0.5 <= args.confidence < 1:
        raise SwarmInputError(f"--confidence must be in [0.5, 1), got {args.confidence}")
    out = args.out or args.file.with_suffix(".model.toml")
    log = load_run_log(args.file)
    truths = read_truth_csv(args.truth, log.ids, log.step_end_times())
    fit = fit_noise(log.commands, log.observations, truths, args.confidence)
    if fit.turn is None and fit.range is None:
        raise SwarmInputError(f"--truth {args.truth}: no step of the recording has true poses for its robots (steps 0, 1, ... of robots {log.ids})")
    result = fit.to_json()
    out.write_text(fit.to_toml(f"noise model of {args.file.name} fitted by swarm calibrate (truth {args.truth.name})"), encoding="utf-8")
    print_report(result)
    print(f"wrote {out}")
    if args.json:
        print_json({**result, "recording": str(args.file), "truth": str(args.truth), "model_file": str(out)})
    return 0


def _fmt(v) -> str:
    return "-" if v is None else f"{v:.4g}"


def print_report(result: dict) -> None:
    """The fitted values, their intervals, the tests and the sample counts, one line each."""
    level = f"{100 * result['confidence']:g} %"
    for key in ("turn_sigma_deg", "drive_sigma_frac", "range_sigma_m", "bearing_sigma_deg", "dropout", "sensing_range_m"):
        ci = result["ci"][key]
        interval = "not identified" if ci is None else f"[{_fmt(ci[0])}, {_fmt(ci[1]) if ci[1] is not None else 'not bounded'}]"
        print(f"{key:<18} {_fmt(result[key]):>10}   {level} CI {interval}")
    for name, t in result["systematic"].items():
        verdict = "significant" if t["significant"] else "not significant"
        print(f"{name:<18} {_fmt(t['estimate']):>10}   CI [{_fmt(t['ci'][0])}, {_fmt(t['ci'][1])}], p = {t['p_value']:.3g} ({verdict})")
    s = result["samples"]
    print(f"samples: {s['turns']} turns, {s['drives']} drives, {s['observations']} observations, "
          f"{s['pairs_in_range']} of {s['pairs']} pairs within the sensing range")
    if result["unidentified"]:
        print(f"not identified (defaults kept in the model file): {', '.join(result['unidentified'])}")
