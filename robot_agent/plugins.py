"""Drivers a lab writes itself, loaded by ``--driver`` (docs/drivers.md).

``--driver`` takes, besides ``sim``, ``gateway`` and ``ros2``:

* ``package.module:Class``: ``Class`` of an importable module (on ``sys.path``, e.g. installed,
  or in the working directory);
* ``path/to/file.py:Class``: ``Class`` of a Python file;
* ``NAME``: the entry point ``NAME`` of the group ``inchworm_swarm.drivers`` of an installed
  package (``[project.entry-points."inchworm_swarm.drivers"] mybot = "mybot.driver:MyBot"``).

The class must subclass ``robot_agent.driver.Driver``; the agent builds one per robot as
``Class(DriverContext)``. Every problem is a ``SwarmInputError`` naming the ``--driver`` value.
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import inspect
import sys
import types
from importlib.metadata import entry_points
from pathlib import Path

from robot_agent.driver import Driver, DriverContext
from runtime.errors import OptionError, SwarmInputError

ENTRY_POINT_GROUP = "inchworm_swarm.drivers"
BUILT_IN = ("sim", "gateway", "ros2")


def _module(spec: str, name: str) -> types.ModuleType:
    if name.endswith(".py"):
        path = Path(name).expanduser()
        if not path.is_file():
            raise OptionError("driver", f"{spec}: no such file {path}")
        module_name = "inchworm_driver_" + hashlib.sha1(str(path.resolve()).encode()).hexdigest()[:12]
        if module_name in sys.modules:
            return sys.modules[module_name]
        loader_spec = importlib.util.spec_from_file_location(module_name, path)
        if loader_spec is None or loader_spec.loader is None:
            raise OptionError("driver", f"{spec}: cannot load {path} as Python")
        module = importlib.util.module_from_spec(loader_spec)
        sys.modules[module_name] = module
        try:
            loader_spec.loader.exec_module(module)
        except Exception as exc:  # noqa: BLE001 - the lab's module failed: say so in one line
            del sys.modules[module_name]
            raise OptionError("driver", f"{spec}: importing {path} failed: {type(exc).__name__}: {exc}") from None
        return module
    try:
        try:
            return importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if not (_missing(exc, name) and _add_working_directory()):
                raise
            return importlib.import_module(name)  # again, with the working directory searched
    except ModuleNotFoundError as exc:
        if _missing(exc, name):
            raise OptionError("driver", f"{spec}: no module named {name!r}") from None
        raise OptionError("driver", f"{spec}: importing {name} failed: {exc}") from None
    except Exception as exc:  # noqa: BLE001
        raise OptionError("driver", f"{spec}: importing {name} failed: {type(exc).__name__}: {exc}") from None


def _missing(exc: ModuleNotFoundError, name: str) -> bool:
    """Whether ``exc`` says ``name`` itself (or a package above it) is not there, not something it imports."""
    return exc.name is not None and (name == exc.name or name.startswith(exc.name + "."))


def _add_working_directory() -> bool:
    """Put the working directory first on ``sys.path`` as ``python -m`` does (the ``swarm`` script's path has its own
    folder instead); False if it is searched already."""
    cwd = Path.cwd().resolve()
    for entry in sys.path:
        try:
            if Path(entry or ".").resolve() == cwd:
                return False
        except OSError:
            continue
    sys.path.insert(0, str(cwd))
    importlib.invalidate_caches()
    return True


def driver_class(spec: str) -> type[Driver]:
    """The driver class ``spec`` names (not ``sim``, ``gateway`` or ``ros2``, which the agent builds itself)."""
    if ":" in spec:
        module_name, _, attr = spec.rpartition(":")
        if not module_name or not attr:
            raise OptionError("driver", f"{spec}: expected package.module:Class or file.py:Class")
        cls = getattr(_module(spec, module_name), attr, None)
        if cls is None:
            raise OptionError("driver", f"{spec}: {module_name} has no {attr}")
    else:
        found = [ep for ep in entry_points(group=ENTRY_POINT_GROUP) if ep.name == spec]
        if not found:
            raise OptionError("driver", f"{spec}: not sim, gateway, ros2, package.module:Class, file.py:Class "
                                        f"or an installed {ENTRY_POINT_GROUP} entry point")
        try:
            cls = found[0].load()
        except Exception as exc:  # noqa: BLE001
            raise OptionError("driver", f"{spec}: loading the entry point {found[0].value} failed: {type(exc).__name__}: {exc}") from None
    if not (isinstance(cls, type) and issubclass(cls, Driver)):
        raise OptionError("driver", f"{spec}: {cls!r} is not a driver (a subclass of robot_agent.driver.Driver)")
    if inspect.isabstract(cls):
        raise OptionError("driver", f"{spec}: {cls.__name__} does not implement {', '.join(sorted(cls.__abstractmethods__))}")
    return cls


def build_driver(spec: str, cls: type[Driver], context: DriverContext) -> Driver:
    """``cls(context)``; a failure to build is a ``SwarmInputError`` naming ``spec`` and the robot."""
    try:
        return cls(context)  # type: ignore[call-arg]  # drivers take their context (docs/drivers.md); the ABC declares no constructor
    except OptionError:
        raise  # one of its options (it names the option and the value)
    except SwarmInputError as exc:
        raise OptionError("driver", f"{spec}: robot {context.robot}: {exc}") from None
    except Exception as exc:  # noqa: BLE001 - the lab's constructor failed (bad option, robot not found, ...)
        raise OptionError("driver", f"{spec}: robot {context.robot}: the driver failed to start: {type(exc).__name__}: {exc}") from None
