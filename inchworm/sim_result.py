"""What ``inchworm.simulate`` returns: the run (a ``RunResult``) with the options it ran, and the ``swarm sim --json``
object of both (``SimResult.to_json``). Loaded with the run, not when ``inchworm.simulation`` is imported."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, fields
from typing import Any

from coordinator.run_result import RunResult
from inchworm.simulation import SimOptions, config_rows, contacts_json, fallback_steps, world_json


@dataclass(eq=False)
class SimResult(RunResult):
    """A simulated run (every ``RunResult`` field and method) and the ``SimOptions`` it ran (``options``, its
    trajectory the ``Trajectory`` followed)."""

    options: SimOptions | None = None

    @classmethod
    def of(cls, result: RunResult, options: SimOptions) -> SimResult:
        """``result``, the run of ``options``, with them."""
        return cls(**{f.name: getattr(result, f.name) for f in fields(RunResult)}, options=options)

    def to_json(self, plots: Sequence[str] = ()) -> dict[str, Any]:
        """The object ``swarm sim --json`` prints: ``method``, ``localizer``, ``seed``, ``pf``, ``mc_start`` and
        ``mc_emax`` (the anchor search's), ``configs`` (the rows of ``configs.csv``), ``fallback_steps``, ``plots``
        (the figures written of the run: ``inchworm.plots.write_run_plots``), the bodies' keys
        (``inchworm.simulation.contacts_json``) and the world's (``world_json``)."""
        o = self.options
        if o is None:
            raise ValueError("SimResult.to_json needs the options of the run (SimResult.of(result, options))")
        return {"method": o.method if isinstance(o.method, str) else self.method, "localizer": _name(o.localizer), "seed": o.seed,
                "pf": self.pf(), "mc_start": o.selection.mc_start, "mc_emax": o.selection.mc_emax, "configs": config_rows(self),
                "fallback_steps": len(fallback_steps(self)), "plots": list(plots),
                **contacts_json(self, o.model.robot_radius_m), **world_json(self, o.world)}


def _name(localizer: object) -> str:
    """A localizer's name: the registered name given, or its object's ``name`` (else its class's)."""
    return localizer if isinstance(localizer, str) else str(getattr(localizer, "name", type(localizer).__name__))
