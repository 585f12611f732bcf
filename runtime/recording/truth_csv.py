"""True poses at step ends as CSV (docs/calibration.md): what an external tracker gives ``swarm calibrate``.

    robot,step,x,y,heading
    0,0,0.1,0.2,1.5707963
    0,1,0.35,0.21,0.0412

One row per robot and step: the robot's true pose (x, y in metres, heading in radians,
counter-clockwise from the x axis, any range) at the end of global step ``step`` (0: before
the first motion), in the same world frame for every robot. Columns may come in any order;
extra columns are ignored. ``read_truth_csv`` checks every row and raises ``SwarmInputError``
naming the file, the row (line number) and what is wrong.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Collection, Iterable
from pathlib import Path

import numpy as np

from runtime.errors import SwarmInputError

COLUMNS = ("robot", "step", "x", "y", "heading")


def write_truth_csv(path: str | Path, rows: Iterable[tuple[int, int, float, float, float]]) -> int:
    """Write ``(robot, step, x, y, heading)`` rows (sorted by step, then robot); the number written."""
    rows = sorted(rows, key=lambda r: (r[1], r[0]))
    with open(path, "w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(COLUMNS)
        for robot, step, x, y, heading in rows:
            w.writerow([int(robot), int(step), repr(float(x)), repr(float(y)), repr(float(heading))])
    return len(rows)


def read_truth_csv(path: str | Path, robots: Collection[int] | None = None) -> dict[tuple[int, int], np.ndarray]:
    """``{(robot, step): pose (3,)}`` of the CSV ``path``; ``robots``: the run's ids (any other id is an error)."""
    path = Path(path)
    known = None if robots is None else {int(r) for r in robots}
    try:
        f = open(path, newline="", encoding="utf-8")
    except OSError as exc:
        raise SwarmInputError(f"--truth {path}: cannot read it: {exc.strerror or exc}") from None
    out: dict[tuple[int, int], np.ndarray] = {}
    with f:
        reader = csv.DictReader(f)
        try:
            header = reader.fieldnames or []
        except (csv.Error, UnicodeDecodeError) as exc:
            raise SwarmInputError(f"--truth {path}: line 1: not CSV: {exc}") from None
        missing = [c for c in COLUMNS if c not in [h.strip() for h in header]]
        if missing:
            raise SwarmInputError(f"--truth {path}: line 1: missing column{'s' if len(missing) > 1 else ''} "
                                  f"{', '.join(missing)} (need {','.join(COLUMNS)})")
        try:
            for row in reader:
                line = reader.line_num
                row = {(k or "").strip(): (v or "").strip() for k, v in row.items() if k is not None}
                out_key, pose = _row(row, line, path, known)
                if out_key in out:
                    raise SwarmInputError(f"--truth {path}: line {line}: robot {out_key[0]} step {out_key[1]} given twice")
                out[out_key] = pose
        except (csv.Error, UnicodeDecodeError) as exc:
            raise SwarmInputError(f"--truth {path}: line {reader.line_num}: not CSV: {exc}") from None
    if not out:
        raise SwarmInputError(f"--truth {path}: no rows after the header")
    return out


def _row(row: dict[str, str], line: int, path: Path, known: set[int] | None) -> tuple[tuple[int, int], np.ndarray]:
    where = f"--truth {path}: line {line}"
    ints = []
    for col in ("robot", "step"):
        text = row.get(col, "")
        try:
            value = int(text)
        except ValueError:
            raise SwarmInputError(f"{where}: {col} must be an integer >= 0, got {text!r}") from None
        if value < 0:
            raise SwarmInputError(f"{where}: {col} must be an integer >= 0, got {text!r}")
        ints.append(value)
    robot, step = ints
    if known is not None and robot not in known:
        raise SwarmInputError(f"{where}: robot {robot} is not a robot of the recording (robots {sorted(known)})")
    pose = []
    for col in ("x", "y", "heading"):
        text = row.get(col, "")
        try:
            value = float(text)
        except ValueError:
            raise SwarmInputError(f"{where}: {col} must be a number, got {text!r}") from None
        if not math.isfinite(value):
            raise SwarmInputError(f"{where}: {col} must be finite, got {text!r}")
        pose.append(value)
    return (robot, step), np.array(pose)
