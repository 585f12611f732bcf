"""Swarm localization behind one interface (Section 5): the paper's method and a joint alternative.

A ``Localizer`` turns the pre-step estimate, the step's commands and the post-step
observations into the post-step estimate. The motion strategy only talks to this
interface, which is what lets it "work with any localization method". Localizers are
made by name (``registry``: built-in, registered in code, or installed as plugins); the
executor and the anchor selection's Monte Carlo receive the same object.

The localizer classes are imported on first use (they need scipy): importing this package,
or its ``registry`` to list names for a parser, stays cheap.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from coordinator.localization.interface import Localizer
from coordinator.localization.registry import localizer_names, make_localizer, register_localizer

if TYPE_CHECKING:
    from coordinator.localization.joint import JointLocalizer
    from coordinator.localization.paper import PaperLocalizer
    from coordinator.localization.topology import Topology


_LAZY = {
    "JointLocalizer": "coordinator.localization.joint",
    "PaperLocalizer": "coordinator.localization.paper",
    "Topology": "coordinator.localization.topology",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["Localizer", "JointLocalizer", "PaperLocalizer", "Topology", "localizer_names", "make_localizer", "register_localizer"]
