"""``swarm calibrate RUN.mcap --truth TRUTH.csv``: fit the noise model to a lab's robots (docs/calibration.md).

    swarm calibrate recordings/lab.mcap --truth tracker.csv [--out lab-model.toml] [--json]

Fits turn and drive noise, range and bearing noise, dropout and sensing range by maximum
likelihood (``inchworm.noise_calibration``), prints them and writes the model file (TOML)
that ``--model FILE`` reads. The ``--json`` last line
holds ``turn_sigma_deg``, ``drive_sigma_frac``, ``range_sigma_m``, ``bearing_sigma_deg``,
``dropout``, ``sensing_range_m`` (the units of the flags of the same names), ``ci``,
``systematic``, ``samples``, ``unidentified`` and ``model_file``.
Exit status 0, 2 on bad input (unreadable recording, bad CSV row, nothing to fit).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from swarm_cli.options import add_json_option, print_result


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
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
    from inchworm.noise_calibration import calibrate_noise  # noqa: PLC0415 - scipy and numpy only when a command runs

    result = calibrate_noise(args.file, args.truth, args.out, args.confidence)
    return print_result(result, args.json, f"wrote {result.model_file}")
