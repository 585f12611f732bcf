"""Benchmarks: typed options in, a ``BenchResult`` out (rows, ``to_json()``, ``report()``, ``plot(ax)``).

Speed numbers vary with the machine and its load; a benchmark prints them, no test times them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from matplotlib.axes import Axes


@dataclass
class BenchResult:
    """One benchmark's rows, the JSON object ``swarm bench ... --json`` prints, and its table.

    ``x`` and ``y`` name the row keys ``plot`` draws (e.g. swarm size and median time), ``ylabel`` its axis.
    """

    rows: list[dict[str, Any]]
    summary: dict[str, Any]
    table: str
    x: str
    y: str
    ylabel: str
    heading: str

    def to_json(self) -> dict[str, Any]:
        return self.summary

    def report(self) -> str:
        return self.table

    def plot(self, ax: Axes) -> Axes:
        """``y`` against ``x`` over the rows (axes from 0)."""
        from inchworm.plots import title  # noqa: PLC0415

        rows = [r for r in self.rows if r.get(self.y) is not None]
        ax.plot([r[self.x] for r in rows], [r[self.y] for r in rows], "o-")
        ax.set_xlabel(self.x)
        ax.set_ylabel(self.ylabel)
        ax.set_xlim(left=0)
        ax.set_ylim(bottom=0)
        ax.grid(alpha=0.3)
        title(ax, self.heading)
        return ax
