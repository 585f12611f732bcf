"""Command-line options shared by every command that simulates or localizes."""

from __future__ import annotations

import argparse
import json
import math

from runtime.config import ModelConfig


def add_model_options(parser: argparse.ArgumentParser) -> None:
    """Noise and sensing options mirroring ``ModelConfig`` (defaults: the documented ones)."""
    d = ModelConfig()
    g = parser.add_argument_group("model (noise and sensing; SI units, angles in degrees)")
    g.add_argument("--turn-sigma-deg", type=float, default=math.degrees(d.turn_sigma_rad), help="turn noise std (default 3)")
    g.add_argument("--drive-sigma-frac", type=float, default=d.drive_sigma_frac, help="drive noise std as a fraction of the distance (default 0.05)")
    g.add_argument("--range-sigma", type=float, default=d.range_sigma_m, help="range noise std in m (default 0.01)")
    g.add_argument("--bearing-sigma-deg", type=float, default=math.degrees(d.bearing_sigma_rad), help="bearing noise std (default 2)")
    g.add_argument("--sensing-range", type=float, default=d.sensing_range_m, help="sensing range in m (default 0.5)")
    g.add_argument("--dropout", type=float, default=d.dropout_prob, help="probability an observation is lost (default 0)")


def model_config(args: argparse.Namespace) -> ModelConfig:
    """``ModelConfig`` from the options added by ``add_model_options``."""
    return ModelConfig(
        turn_sigma_rad=math.radians(args.turn_sigma_deg),
        drive_sigma_frac=args.drive_sigma_frac,
        range_sigma_m=args.range_sigma,
        bearing_sigma_rad=math.radians(args.bearing_sigma_deg),
        sensing_range_m=args.sensing_range,
        dropout_prob=args.dropout,
    )


def add_localizer_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--localizer", choices=["paper", "joint"], default="paper", help="localization method (default: paper, Section 5)")


def add_json_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--json", action="store_true", help="print one JSON object as the last line")


def print_json(obj: object) -> None:
    """The machine-readable result: one JSON object on one line."""
    print(json.dumps(obj, separators=(",", ":")), flush=True)
