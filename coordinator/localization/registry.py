"""Localizers by name: the built-in ones, those registered in code and those installed as plugins.

A localizer factory is called as ``factory(cfg, **options)`` and returns an object with the
``Localizer`` interface (``coordinator.localization``). Three ways to make one known by name:

* the built-ins ``paper`` (Section 5) and ``joint`` (Section 5.3);
* ``register_localizer(name, factory)`` from Python (a notebook, a study script, a test); a local worker pool's
  processes receive it (``inchworm.runner.pool_localizers``), so its factory must be picklable: a class or function
  at the top level of a module;
* an installed package declaring an entry point in the group ``inchworm_swarm.localizers``
  (``[project.entry-points."inchworm_swarm.localizers"] name = "package.module:factory"``): every
  ``swarm`` command, its worker processes and the processes of a distributed run see it.

Names are listed without importing anything (a parser's ``--localizer`` choices); a factory is
imported when a localizer is made.

A localizer whose result depends on its inputs alone, with everything it carries to its next step kept in
the ``SwarmEstimate`` it returns (e.g. ``joint``), is reproduced exactly by ``swarm replay --check`` and by a
coordinator that takes a run over from a checkpoint (docs/localization.md).
"""

from __future__ import annotations

import importlib
import inspect
from collections.abc import Callable
from importlib.metadata import entry_points
from typing import TYPE_CHECKING, Any, cast

from runtime.errors import SwarmInputError

if TYPE_CHECKING:
    from coordinator.localization.interface import Localizer
    from runtime.models.config import ModelConfig

ENTRY_POINT_GROUP = "inchworm_swarm.localizers"
BUILTIN_LOCALIZERS = ("paper", "joint")  # the paper's method first: the default of every command
DEFAULT_LOCALIZER = BUILTIN_LOCALIZERS[0]

LocalizerFactory = Callable[..., "Localizer"]
_BUILTIN_PATHS = {
    "paper": "coordinator.localization.paper:PaperLocalizer",
    "joint": "coordinator.localization.joint:JointLocalizer",
}
_registered: dict[str, LocalizerFactory] = {}


def register_localizer(name: str, factory: LocalizerFactory) -> None:
    """Make ``factory(cfg, **options)`` the localizer called ``name`` (replacing an earlier registration
    of that name; the built-in names cannot be taken)."""
    if not isinstance(name, str) or not name or name != name.strip() or "," in name:
        raise SwarmInputError(f"a localizer name must be a non-empty word without commas, got {name!r}")
    if name in BUILTIN_LOCALIZERS:
        raise SwarmInputError(f"localizer {name!r} is built in and cannot be registered again")
    if not callable(factory):
        raise SwarmInputError(f"the factory of localizer {name!r} must be callable, got {factory!r}")
    _registered[name] = factory


def unregister_localizer(name: str) -> None:
    """Forget a localizer registered with ``register_localizer`` (no-op when unknown)."""
    _registered.pop(name, None)


def registered_localizers() -> dict[str, LocalizerFactory]:
    """The localizers registered with ``register_localizer`` in this process, by name (a worker pool passes them on)."""
    return dict(_registered)


def _plugins() -> dict[str, Any]:
    """Entry points of the ``inchworm_swarm.localizers`` group by name (not loaded)."""
    return {ep.name: ep for ep in entry_points(group=ENTRY_POINT_GROUP)}


def localizer_names() -> tuple[str, ...]:
    """Every known localizer: the built-ins, then the registered ones, then the installed plugins."""
    names = [*BUILTIN_LOCALIZERS, *_registered]
    return tuple(names + [name for name in _plugins() if name not in names])


def _factory(name: str) -> LocalizerFactory:
    if name in _BUILTIN_PATHS:
        module, _, attr = _BUILTIN_PATHS[name].partition(":")
        return cast(LocalizerFactory, getattr(importlib.import_module(module), attr))
    if name in _registered:
        return _registered[name]
    plugin = _plugins().get(name)
    if plugin is None:
        raise SwarmInputError(f"unknown localizer {name!r}; choose one of {', '.join(localizer_names())}")
    try:
        return cast(LocalizerFactory, plugin.load())  # what the entry point names: checked when called
    except Exception as exc:  # noqa: BLE001 - a broken plugin is the user's input: one clear line
        raise SwarmInputError(f"localizer plugin {name!r} ({plugin.value}) cannot be loaded: {exc}") from None


def make_localizer(name: str, cfg: ModelConfig, **options: Any) -> Localizer:
    """The localizer called ``name`` for the model ``cfg``, with ``options`` (e.g. ``huber=3.0``;
    ``constrain_gauge=False`` for ``joint``) passed to its factory."""
    factory = _factory(name)
    try:
        inspect.signature(factory).bind(cfg, **options)
    except TypeError as exc:
        raise SwarmInputError(f"localizer {name!r} does not take options {sorted(options)}: {exc}") from None
    except ValueError:  # no signature to check (a builtin): the call itself will tell
        pass
    return factory(cfg, **options)


__all__ = [
    "BUILTIN_LOCALIZERS",
    "DEFAULT_LOCALIZER",
    "ENTRY_POINT_GROUP",
    "localizer_names",
    "make_localizer",
    "register_localizer",
    "registered_localizers",
    "unregister_localizer",
]
