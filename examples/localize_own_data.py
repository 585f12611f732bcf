"""Localize robots from your own range/bearing measurements (format: docs/localize-input.md).

    python examples/localize_own_data.py [FILE.json] [--range-sigma M] [--bearing-sigma-deg DEG]
        [--sensing-range M] [--model FILE.toml] [--localizer paper|joint] [--no-robust]

Without a file, three robots' measurements of each other are localized (no prior: the
answer is their layout in the frame of robot 0, which should come out as ``LAYOUT``). Ranges
in metres, bearings in radians in the observing robot's frame.

The +- printed is only as honest as the noise model: give your sensor's range and bearing
sigmas and sensing range as options, or a model file (``--model``, as ``swarm calibrate``
writes it; options override its values). The defaults are the project's (10 mm, 2 deg, 0.5 m).
Rows whose whitened residual is too large (a wrong robot id, a reflection) are printed as
suspects; bad input gets a one-line error and exit code 2.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import replace
from pathlib import Path
from typing import NoReturn

import inchworm
from runtime.errors import LocalizationError, SwarmInputError
from runtime.models.config import ModelConfig
from runtime.models.model_file import load_model

LAYOUT = {0: (0.0, 0.0, 0.0), 1: (0.4, 0.0, math.pi), 2: (0.0, 0.3, math.pi / 2)}  # what the tape measure would give (m, rad)
ERRORS = [(0.001, 0.004), (-0.002, -0.01), (-0.001, 0.02), (0.002, 0.01), (0.0, -0.02)]  # range (m) and bearing (rad) errors
PAIRS = [(0, 1), (0, 2), (1, 0), (1, 2), (2, 0)]
PROG = "localize_own_data.py"


def measured() -> dict:
    """Range/bearing rows [observer, observed, range, bearing] of the pairs in ``PAIRS``, a few mm and mrad off."""
    rows = []
    for (i, j), (dr, db) in zip(PAIRS, ERRORS, strict=True):
        (xi, yi, hi), (xj, yj, _) = LAYOUT[i], LAYOUT[j]
        bearing = math.atan2(yj - yi, xj - xi) - hi
        rows.append([i, j, math.hypot(xj - xi, yj - yi) + dr, math.atan2(math.sin(bearing), math.cos(bearing)) + db])
    return {"robots": list(LAYOUT), "observations": rows}


def fail(message: str) -> NoReturn:
    """One line on stderr, exit code 2 (bad input, as ``swarm localize``)."""
    print(f"{PROG}: error: {message}", file=sys.stderr)
    raise SystemExit(2)


def number(low: float, strict: bool):
    """An argparse type: a finite float >= ``low`` (> when ``strict``)."""
    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        if not math.isfinite(value) or value < low or (strict and value == low):
            raise argparse.ArgumentTypeError(f"must be {'>' if strict else '>='} {low:g}, got {text}")
        return value
    return parse


def parse_args(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog=PROG, description="Localize robots from range/bearing rows (docs/localize-input.md).")
    p.error = fail  # type: ignore[method-assign]  # one line, exit 2
    p.add_argument("file", nargs="?", type=Path, help="input JSON (default: three robots measured by hand)")
    p.add_argument("--range-sigma", type=number(0.0, False), help="range noise std in m (default: the model's, 0.01)")
    p.add_argument("--bearing-sigma-deg", type=number(0.0, False), help="bearing noise std in degrees (default: the model's, 2)")
    p.add_argument("--sensing-range", type=number(0.0, True), help="sensing range in m (default: the model's, 0.5)")
    p.add_argument("--model", type=Path, metavar="FILE", help="noise model file (TOML, docs/calibration.md); the options above override it")
    p.add_argument("--localizer", choices=("paper", "joint"), default="joint", help="localization method (default joint)")
    p.add_argument("--no-robust", action="store_true", help="plain least squares (no Huber loss against outliers)")
    return p.parse_args(argv)


def noise_model(args: argparse.Namespace) -> ModelConfig:
    """The model file's values (or the defaults), overridden by the options given."""
    base = load_model(args.model) if args.model is not None else ModelConfig()
    given = {"range_sigma_m": args.range_sigma, "sensing_range_m": args.sensing_range,
             "bearing_sigma_rad": None if args.bearing_sigma_deg is None else math.radians(args.bearing_sigma_deg)}
    return replace(base, **{k: v for k, v in given.items() if v is not None})


def main(argv: list[str]) -> int:
    args = parse_args(argv)
    try:
        cfg = noise_model(args)
        answer = inchworm.localize(args.file if args.file is not None else measured(), cfg, args.localizer, robust=not args.no_robust)
    except (SwarmInputError, LocalizationError) as exc:
        fail(str(exc))
    print(f"noise model: range {cfg.range_sigma_m:g} m, bearing {math.degrees(cfg.bearing_sigma_rad):g} deg, "
          f"sensing range {cfg.sensing_range_m:g} m")
    for robot in answer.robots:
        heading = "unknown (it observed nobody)" if robot.heading is None else f"{math.degrees(robot.heading):+6.1f} deg"
        print(f"robot {robot.id}: x {robot.x:+.3f} m, y {robot.y:+.3f} m, +- {robot.delta_p:.3f} m, heading {heading}")
    for robot_id, reason in sorted(answer.excluded.items()):
        print(f"left out robot {robot_id}: {reason}")
    for line in answer.warnings:
        print(f"warning: {line}")
    print(json.dumps({k: v for k, v in answer.to_json().items() if k not in ("robots", "observations")}))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
