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

from inchworm.noise_calibration import CalibrateOptions, calibrate_noise  # light: scipy and numpy only when fitting
from swarm_cli.options import add_json_option, print_result
from swarm_cli.schema import add_fields, options_of


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("calibrate", help="fit the noise model (motion, sensing) to a recorded run and a tracker's true poses")
    p.add_argument("file", type=Path, help="MCAP recording of the run (swarm coordinator / swarm record)")
    add_fields(p, CalibrateOptions, exclude=("recording",))
    add_json_option(p)
    p.set_defaults(run=run)


def options(args: argparse.Namespace) -> CalibrateOptions:
    """The ``CalibrateOptions`` of the flags (the recording: the file positional)."""
    return options_of(args, CalibrateOptions, recording=args.file)


def run(args: argparse.Namespace) -> int:
    result = calibrate_noise(options(args))
    return print_result(result, args.json, f"wrote {result.model_file}")
