"""Localize robots from your own range/bearing measurements (format: docs/localize-input.md).

    python examples/localize_own_data.py [FILE.json]

Without a file, three robots' measurements of each other are localized (no prior: the
answer is their layout in the frame of robot 0, which should come out as ``LAYOUT``). Ranges in metres, bearings in
radians in the observing robot's frame.
"""

from __future__ import annotations

import json
import math
import sys

import inchworm
from runtime.models.config import ModelConfig

LAYOUT = {0: (0.0, 0.0, 0.0), 1: (0.4, 0.0, math.pi), 2: (0.0, 0.3, math.pi / 2)}  # what the tape measure would give (m, rad)
ERRORS = [(0.001, 0.004), (-0.002, -0.01), (-0.001, 0.02), (0.002, 0.01), (0.0, -0.02)]  # range (m) and bearing (rad) errors
PAIRS = [(0, 1), (0, 2), (1, 0), (1, 2), (2, 0)]


def measured() -> dict:
    """Range/bearing rows [observer, observed, range, bearing] of the pairs in ``PAIRS``, a few mm and mrad off."""
    rows = []
    for (i, j), (dr, db) in zip(PAIRS, ERRORS, strict=True):
        (xi, yi, hi), (xj, yj, _) = LAYOUT[i], LAYOUT[j]
        bearing = math.atan2(yj - yi, xj - xi) - hi
        rows.append([i, j, math.hypot(xj - xi, yj - yi) + dr, math.atan2(math.sin(bearing), math.cos(bearing)) + db])
    return {"robots": list(LAYOUT), "observations": rows}


def main() -> None:
    source = sys.argv[1] if len(sys.argv) > 1 else measured()
    answer = inchworm.localize(source, ModelConfig(range_sigma_m=0.005, bearing_sigma_rad=math.radians(1.0)), "joint")
    for robot in answer["robots"]:
        heading = "-" if robot["heading"] is None else f"{math.degrees(robot['heading']):+6.1f} deg"
        print(f"robot {robot['id']}: x {robot['x']:+.3f} m, y {robot['y']:+.3f} m, heading {heading}, +- {robot['delta_p']:.3f} m")
    for left_out in answer["excluded"]:
        print(f"left out robot {left_out['id']}: {left_out['reason']}")
    print(json.dumps({k: v for k, v in answer.items() if k != "robots"}))


if __name__ == "__main__":
    main()
