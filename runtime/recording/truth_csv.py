"""True poses at step ends as CSV (docs/calibration.md): what an external tracker gives ``swarm calibrate``.

    robot,step,x,y,heading
    0,0,0.1,0.2,1.5707963
    0,1,0.35,0.21,0.0412

One row per robot and step: the robot's true pose (x, y in metres, heading in radians,
counter-clockwise from the x axis, any range) at the end of global step ``step`` (0: before
the first motion), in the same world frame for every robot. A tracker that samples on its own
clock may give ``time`` (s since the Unix epoch) instead of ``step``: its poses are interpolated at
the step ends. Columns may come in any order; extra columns are ignored. ``read_truth_csv`` checks every row and raises ``SwarmInputError``
naming the file, the row (line number) and what is wrong.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Collection, Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from runtime.errors import OptionError, SwarmInputError

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


def read_truth_csv(path: str | Path, robots: Collection[int] | None = None,
                   step_times: Mapping[tuple[int, int], float] | None = None) -> dict[tuple[int, int], np.ndarray]:
    """``{(robot, step): pose (3,)}`` of the CSV ``path``; ``robots``: the run's ids (any other id is an error).

    A CSV with a ``time`` column instead of ``step`` (seconds since the Unix epoch, on the clock of the
    machines that ran the agents) is interpolated at ``step_times`` ((robot, step) -> s: when each step
    ended, ``RunLog.step_end_times``): linearly in x, y and the unwrapped heading, never extrapolated
    (a step outside a robot's tracked span gets no pose).
    """
    path = Path(path)
    known = None if robots is None else {int(r) for r in robots}
    try:
        f = open(path, newline="", encoding="utf-8")
    except OSError as exc:
        raise OptionError("truth", f"{path}: cannot read it: {exc.strerror or exc}") from None
    rows: dict[tuple[int, float], np.ndarray] = {}
    with f:
        reader = csv.DictReader(f)
        try:
            header = [h.strip() for h in reader.fieldnames or []]
        except (csv.Error, UnicodeDecodeError) as exc:
            raise OptionError("truth", f"{path}: line 1: not CSV: {exc}") from None
        by_time = "step" not in header and "time" in header
        need = ("robot", "time", "x", "y", "heading") if by_time else COLUMNS
        missing = [c for c in need if c not in header]
        if missing:
            raise OptionError("truth", f"{path}: line 1: missing column{'s' if len(missing) > 1 else ''} "
                                       f"{', '.join(missing)} (need {','.join(COLUMNS)}, or time instead of step)")
        try:
            for row in reader:
                line = reader.line_num
                row = {(k or "").strip(): (v or "").strip() for k, v in row.items() if k is not None}
                key, pose = _row(row, line, path, known, by_time)
                if key in rows:
                    raise OptionError("truth", f"{path}: line {line}: robot {key[0]} {'time' if by_time else 'step'} "
                                               f"{row['time' if by_time else 'step']} given twice")
                rows[key] = pose
        except (csv.Error, UnicodeDecodeError) as exc:
            raise OptionError("truth", f"{path}: line {reader.line_num}: not CSV: {exc}") from None
    if not rows:
        raise OptionError("truth", f"{path}: no rows after the header")
    if not by_time:
        return {(robot, int(step)): pose for (robot, step), pose in rows.items()}
    if step_times is None:
        raise OptionError("truth", f"{path}: has times, not steps, and no step times to match them to")
    return _at_steps(rows, step_times)


def _at_steps(rows: dict[tuple[int, float], np.ndarray], step_times: Mapping[tuple[int, int], float]) -> dict[tuple[int, int], np.ndarray]:
    """The tracked poses ``rows`` ((robot, time) -> pose) interpolated at each robot's step ends."""
    out: dict[tuple[int, int], np.ndarray] = {}
    for robot in sorted({r for r, _ in rows}):
        times = np.array(sorted(t for r, t in rows if r == robot))
        track = np.array([rows[(robot, t)] for t in times])
        heading = np.unwrap(track[:, 2])
        for (r, step), t in step_times.items():
            if r == robot and times[0] <= t <= times[-1]:
                x, y, h = (np.interp(t, times, v) for v in (track[:, 0], track[:, 1], heading))
                out[(robot, step)] = np.array([x, y, (h + np.pi) % (2 * np.pi) - np.pi])
    return out


def _count(row: dict[str, str], col: str, where: str) -> int:
    """Column ``col`` of ``row`` as an integer >= 0, or ``OptionError`` naming the line of the ``truth`` file."""
    text = row.get(col, "")
    try:
        value = int(text)
    except ValueError:
        value = -1
    if value < 0:
        raise OptionError("truth", f"{where}: {col} must be an integer >= 0, got {text!r}")
    return value


def _row(row: dict[str, str], line: int, path: Path, known: set[int] | None, by_time: bool) -> tuple[tuple[int, float], np.ndarray]:
    where = f"{path}: line {line}"
    robot = _count(row, "robot", where)
    if known is not None and robot not in known:
        raise OptionError("truth", f"{where}: robot {robot} is not a robot of the recording (robots {sorted(known)})")
    when = _finite(row, "time", where) if by_time else _count(row, "step", where)
    return (robot, when), np.array([_finite(row, col, where) for col in ("x", "y", "heading")])


def _finite(row: dict[str, str], col: str, where: str) -> float:
    text = row.get(col, "")
    try:
        value = float(text)
    except ValueError:
        raise OptionError("truth", f"{where}: {col} must be a number, got {text!r}") from None
    if not math.isfinite(value):
        raise OptionError("truth", f"{where}: {col} must be finite, got {text!r}")
    return value


def export_truth(src: str | Path, out: str | Path) -> dict[str, Any]:
    """Write the simulated true poses at step ends of the recording ``src`` to the CSV ``out`` (``write_truth_csv``):
    its path, rows, robots, steps and first / last step; ``SwarmInputError`` if the recording holds none."""
    from runtime.recording.run_log import load_run_log  # noqa: PLC0415

    log = load_run_log(src)
    if not log.truths:
        raise SwarmInputError(f"{src}: the recording holds no true poses (TruthMessage): only simulated runs have them")
    n = write_truth_csv(out, [(robot, step, *pose) for (robot, step), pose in log.truths.items()])
    steps = sorted({step for _, step in log.truths})
    return {"path": str(out), "rows": n, "robots": len(log.ids), "steps": len(steps), "first_step": steps[0], "last_step": steps[-1]}
