"""The state a run has recorded after a step, from which another coordinator continues it (docs/failure-model.md).

``RunState`` is what the executor needs to go on exactly where it was: the configuration in
progress and the next group of its plan, the estimate with its covariance, the plan and the
robots it was made for and how the body constraint split it (``Regrouping``), the lost robots, the anchor selection's random state (its number of
searches, ``AnchorSelector.calls``) and the records of the steps and configurations done (so
the final summary, P_f and ``--result`` are those of one uninterrupted run). It travels as the
JSON ``state`` of a ``Checkpoint`` message; float arrays travel as base64 of their little-endian
float64 bytes with their shape (``{"f64": ..., "shape": [...]}``), so a state read back is bit for
bit the one written (500 robots after 20 steps: 2 MB, encoded or read in about 30 ms here).

The current estimate travels with everything a localizer carries from one step to the next in its
``SwarmEstimate`` (every field, e.g. the joint localizer's (3n, 3n) ``joint`` covariance; an exactly
symmetric matrix as its upper triangle, ``"triangle": "upper"``), so the next step is computed from
the same prior as in the uninterrupted run. The records of the steps done keep poses and 3x3
covariances only. A state that would not fit in ``max_chars`` with those fields (the joint of about
290 robots fills a 4 MiB message) leaves them out and names them in ``"dropped"``: the run then
continues from the per-robot covariances, no longer bit for bit (``RunState.dropped``).
"""

from __future__ import annotations

import base64
import binascii
import dataclasses
import json
from dataclasses import dataclass
from typing import Any, overload

import numpy as np

from coordinator.clearance import Regrouping
from coordinator.legs import LegRecord
from coordinator.plan import Plan
from coordinator.run_result import ConfigRecord, LostRobot, RejoinedRobot, RunResult, StepRecord
from runtime.errors import SwarmInputError
from runtime.models.state import SwarmEstimate
from runtime.models.trajectory import Trajectory


@dataclass(frozen=True)
class RunState:
    """The run after global step ``step``: configuration ``config`` (0-based) in progress, ``group`` its next group."""

    step: int
    config: int
    group: int
    estimate: SwarmEstimate
    plan: Plan | None  # the plan of ``config`` (None before it is planned)
    planned_ids: np.ndarray | None  # the robots the plan's indices refer to
    selector_calls: int
    result: RunResult
    finished: bool = False  # the run completed (nothing is left to take over)
    regrouped: Regrouping | None = None  # how the body constraint split the strategy's plan of ``config`` (None: clear)
    dropped: tuple[str, ...] = ()  # fields of ``estimate`` its checkpoint could not carry (read back: they are None)
    legs: tuple[LegRecord, ...] = ()  # the approach legs of ``config`` so far (the last is ``plan``'s; coordinator.legs)

    def to_json(self) -> str:
        """The state as JSON, with everything the estimate carries."""
        return self._json(carry=True)

    def bounded_json(self, max_chars: int) -> tuple[str, list[str]]:
        """The state as JSON within ``max_chars`` if the estimate's carried fields are all that make it too long (they
        are then left out), and the fields left out (module doc)."""
        carried = carried_fields(self.estimate)
        least = sum(np.asarray(getattr(self.estimate, name)).nbytes for name in carried) * 2 // 3  # base64 of a triangle
        if least <= max_chars:  # else not worth encoding (500 robots: 0.3 s)
            text = self._json(carry=True)
            if len(text) <= max_chars or not carried:
                return text, []
        return self._json(carry=False), carried

    def _json(self, carry: bool) -> str:
        r = self.result
        dropped = list(self.dropped) + ([] if carry else carried_fields(self.estimate))
        return json.dumps({
            "step": self.step, "config": self.config, "group": self.group, "finished": self.finished,
            "estimate": _estimate(self.estimate, carry=carry), "dropped": dropped, "plan": _plan(self.plan),
            "planned_ids": None if self.planned_ids is None else self.planned_ids.tolist(),
            "regrouped": _regrouping(self.regrouped), **_legs_json(self.legs),
            "selector_calls": self.selector_calls, "method": r.method, "initial_truth": _array(r.initial_truth),
            "lost": [{"robot": x.robot, "step": x.step, "config": x.config, "reason": x.reason} for x in r.lost],
            "rejoined": [{"robot": x.robot, "step": x.step, "config": x.config} for x in r.rejoined],
            "steps": [{"config": s.config, "step": s.step, "moving": s.moving.tolist(), "commands": _array(s.commands),
                       "estimate": _estimate(s.estimate), "truth": _array(s.truth), "fallback": s.fallback,
                       "truth_ids": None if s.truth_ids is None else s.truth_ids.tolist()} for s in r.steps],
            "configs": [{"config": c.config, "plan": _plan(c.plan), "estimate": _estimate(c.estimate), "truth": _array(c.truth),
                         "planned_ids": None if c.planned_ids is None else c.planned_ids.tolist(),
                         "regrouped": _regrouping(c.regrouped), **_legs_json(c.legs)} for c in r.configs],
        }, separators=(",", ":"))

    @classmethod
    def from_json(cls, text: str, trajectory: Trajectory, initial_estimate: SwarmEstimate) -> RunState:
        """The state ``to_json`` wrote, for the run of ``trajectory`` that started from ``initial_estimate``."""
        try:
            d = json.loads(text)
            result = RunResult(d["method"], trajectory, initial_estimate, _from_array(d["initial_truth"]))
            result.lost = [LostRobot(x["robot"], x["step"], x["config"], x["reason"]) for x in d["lost"]]
            result.rejoined = [RejoinedRobot(x["robot"], x["step"], x["config"]) for x in d["rejoined"]]
            result.steps = [StepRecord(s["config"], s["step"], np.array(s["moving"], dtype=bool), _from_array(s["commands"]),
                                       _from_estimate(s["estimate"]), _from_array(s["truth"]), s["fallback"],
                                       None if s["truth_ids"] is None else np.array(s["truth_ids"], dtype=np.int64))
                            for s in d["steps"]]
            result.configs = [ConfigRecord(c["config"], _from_plan(c["plan"]), None, _from_estimate(c["estimate"]),
                                           _from_array(c["truth"]),
                                           None if c["planned_ids"] is None else np.array(c["planned_ids"], dtype=np.int64),
                                           _from_regrouping(c["regrouped"]), _from_legs(c))
                              for c in d["configs"]]
            return cls(d["step"], d["config"], d["group"], _from_estimate(d["estimate"]), _from_plan(d["plan"]),
                       None if d["planned_ids"] is None else np.array(d["planned_ids"], dtype=np.int64),
                       d["selector_calls"], result, d["finished"], _from_regrouping(d["regrouped"]),
                       tuple(str(x) for x in d.get("dropped", ())),  # written before carried fields: nothing dropped
                       _from_legs(d))
        except (KeyError, TypeError, ValueError, SwarmInputError, binascii.Error) as exc:
            raise SwarmInputError(f"checkpoint state is not readable: {type(exc).__name__}: {exc}") from None


def _array(a: np.ndarray | None) -> dict[str, Any] | None:
    """A float array as base64 of its little-endian float64 bytes, with its shape (exact, compact, fast)."""
    if a is None:
        return None
    a = np.ascontiguousarray(a, dtype="<f8")
    return {"f64": base64.b64encode(a.tobytes()).decode("ascii"), "shape": list(a.shape)}


@overload
def _from_array(d: dict[str, Any]) -> np.ndarray: ...


@overload
def _from_array(d: None) -> None: ...


def _from_array(d: dict[str, Any] | None) -> np.ndarray | None:
    if d is None:
        return None
    values = np.frombuffer(base64.b64decode(d["f64"], validate=True), dtype="<f8").astype(float)
    if d.get("triangle") != "upper":
        return values.reshape(d["shape"])
    k = int(d["shape"][0])
    out = np.zeros((k, k))
    rows, cols = np.triu_indices(k)
    out[rows, cols] = values
    out[cols, rows] = values
    return out


def _symmetric_array(a: np.ndarray) -> dict[str, Any] | None:
    """``_array``, as the upper triangle when ``a`` is a square matrix equal to its transpose bit for bit."""
    a = np.asarray(a, dtype=float)
    if a.ndim != 2 or a.shape[0] != a.shape[1] or not np.array_equal(a, a.T):
        return _array(a)
    upper = _array(a[np.triu_indices(len(a))])
    return None if upper is None else upper | {"shape": list(a.shape), "triangle": "upper"}


BASE_FIELDS = ("ids", "poses", "cov")  # what every estimate is (and what an EstimateMessage carries)


def carried_fields(e: SwarmEstimate) -> list[str]:
    """The fields of ``e`` beyond ids, poses and 3x3 covariances that are set (a localizer's state for its next step)."""
    return [f.name for f in dataclasses.fields(e) if f.name not in BASE_FIELDS and getattr(e, f.name) is not None]


def _estimate(e: SwarmEstimate, carry: bool = False) -> dict[str, Any]:
    """ids, poses and covariances; with ``carry`` every other field that is set (``carried_fields``)."""
    out = {"ids": e.ids.tolist(), "poses": _array(e.poses), "cov": _array(e.cov)}
    return out | ({name: _symmetric_array(getattr(e, name)) for name in carried_fields(e)} if carry else {})


def _from_estimate(d: dict[str, Any]) -> SwarmEstimate:
    carried = {f.name: _from_array(d[f.name]) for f in dataclasses.fields(SwarmEstimate) if f.name not in BASE_FIELDS and d.get(f.name) is not None}
    return SwarmEstimate(np.array(d["ids"], dtype=np.int64), _from_array(d["poses"]), _from_array(d["cov"]), **carried)


def _plan(p: Plan | None) -> dict[str, Any] | None:
    return None if p is None else {"order": p.order.tolist(), "sizes": list(p.sizes)}


@overload
def _from_plan(d: dict[str, Any]) -> Plan: ...


@overload
def _from_plan(d: None) -> None: ...


def _from_plan(d: dict[str, Any] | None) -> Plan | None:
    return None if d is None else Plan(np.array(d["order"], dtype=np.int64), tuple(d["sizes"]))


def _regrouping(r: Regrouping | None) -> dict[str, Any] | None:
    return None if r is None else {"planned": _plan(r.planned), "unclear": list(r.unclear), "bound": r.bound}


def _from_regrouping(d: dict[str, Any] | None) -> Regrouping | None:
    return None if d is None else Regrouping(_from_plan(d["planned"]), tuple(int(x) for x in d["unclear"]), float(d["bound"]))


def _legs_json(legs: tuple[LegRecord, ...]) -> dict[str, Any]:
    """The approach legs as an additive ``legs`` key (none without legs: a state without them is written as before);
    ``held`` only where a robot waits, ``groups_run`` only where the leg was cut short, ``deferred`` only where robots
    stood in their step (``LegRecord``)."""
    return {"legs": [{"plan": _plan(x.plan), "ids": x.ids.tolist(), "targets": _array(x.targets), "staged": x.staged.tolist(),
                      "regrouped": _regrouping(x.regrouped), **({"held": x.held.tolist()} if len(x.held) else {}),
                      **({} if x.groups_run is None else {"groups_run": x.groups_run}),
                      **({"deferred": x.deferred.tolist()} if len(x.deferred) else {})}
                     for x in legs]} if legs else {}


def _from_legs(d: dict[str, Any]) -> tuple[LegRecord, ...]:
    return tuple(LegRecord(_from_plan(x["plan"]), np.array(x["ids"], dtype=np.int64), _from_array(x["targets"]),
                           np.array(x["staged"], dtype=bool), _from_regrouping(x["regrouped"]),
                           np.array(x.get("held", []), dtype=np.int64),
                           None if x.get("groups_run") is None else int(x["groups_run"]),
                           np.array(x.get("deferred", []), dtype=np.int64)) for x in d.get("legs", ()))
