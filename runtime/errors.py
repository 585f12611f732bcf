"""The runtime's errors: one hierarchy, messages that name what is wrong (robot ids, parameters, files).

::

    SwarmError                      everything raised on purpose (catch this one to catch them all)
    |-- SwarmInputError             bad input: malformed values, unknown ids, impossible requests       exit 2
    |   `-- OptionError             an option of a library call out of range; names its ``parameter``   exit 2
    |-- LocalizationError           localization cannot give a trustworthy answer                      exit 2
    |-- SwarmRunError               a run that started failed; ``robots`` names the robots             exit 3
    |                               (coordinator.node.zenoh_backend.AgentError: lost, stopped;
    |                               coordinator.executor.RunAborted; robot_agent.driver.RobotLost)
    |-- SwarmConnectionError        a connection could not be opened, was refused or was lost          exit 2
    |   `-- RunConflictError        another coordinator holds the run (a run has one master)           exit 4
    `-- OutputError                 an output could not be written (disk full, permissions)            exit 5
        `-- RecordingError          a recording failed or stopped the run

The exit codes are those of every ``swarm`` command, mapped from these classes in one place
(``inchworm.entry.exit_code``; docs/development.md). ``SwarmInputError`` is a ``ValueError``,
``SwarmConnectionError`` a ``ConnectionError`` and ``RecordingError`` an ``OSError``, so code that
catches the built-in kinds keeps working. Library errors name Python parameters (``trajectories must
be >= 1``); the command line names the flag instead (``OptionError.parameter``, translated by
``swarm_cli.options``).
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Iterable, Mapping


class SwarmError(Exception):
    """Base of every error the runtime raises on purpose (catch this one to catch them all)."""

    def __reduce__(self) -> tuple[object, ...]:
        """Pickled as its class, ``args`` and attributes, rebuilt without calling ``__init__`` (whose parameters
        differ from ``args`` in many subclasses): an error raised in a process-pool worker reaches its caller."""
        return (_unpickled, (type(self), self.args, self.__dict__))


def _unpickled(cls: type[SwarmError], args: tuple[object, ...], state: dict[str, object]) -> SwarmError:
    """The error ``SwarmError.__reduce__`` pickled (made by the ``__new__`` of its instances' layout: OSError's for a
    ``ConnectionError`` or ``OSError`` among its bases)."""
    error = OSError.__new__(cls) if issubclass(cls, OSError) else Exception.__new__(cls)
    error.args = args
    error.__dict__.update(state)
    return error


class SwarmInputError(SwarmError, ValueError):
    """Bad user input: malformed values, NaN/inf, unknown ids, impossible requests."""


class OptionError(SwarmInputError):
    """An option of a library call is out of range: ``parameter`` is its Python name (the message starts with it,
    ``trajectories must be >= 1, got 0``) and ``options`` the options object that holds it, if any (or, for options
    that are not fields of a dataclass, a mapping of names to flags); the command line says the same with the
    option's flag (``--trajectories must be >= 1, got 0``). The problem names other options in backquotes
    (``"sim needs `pose` or `trajectory`"``): the message shows their names, the command line their flags."""

    def __init__(self, parameter: str, problem: str, options: object | None = None) -> None:
        super().__init__(f"{parameter}{_joined(mentions(problem))}")
        self.parameter, self.problem, self.options = parameter, problem, options

    def flag(self, parameter: str | None = None) -> str:
        """The command-line flag of ``parameter`` (default: this error's): ``option_flag`` of this error's options."""
        return option_flag(self.parameter if parameter is None else parameter, self.options)

    def flag_message(self) -> str:
        """The message as the command line says it: the flags instead of the parameters (its own and those in backquotes)."""
        return f"{self.flag()}{_joined(mentions(self.problem, self.options, flags=True))}"


_MENTION = re.compile(r"`([a-z][a-z0-9_]*)`")  # another option named in a problem


def option_flag(name: str, options: object | None = None) -> str:
    """The command-line flag of the option ``name`` of ``options``: the ``flag`` metadata of the options' dataclass
    field (or the options mapping's entry), else ``--`` and the name with dashes."""
    if isinstance(options, Mapping) and name in options:
        return str(options[name])
    fields = {f.name: f for f in dataclasses.fields(options)} if dataclasses.is_dataclass(options) else {}
    found = fields.get(name)
    return str(found.metadata["flag"]) if found is not None and "flag" in found.metadata else "--" + name.replace("_", "-")


def mentions(text: str, options: object | None = None, *, flags: bool = False) -> str:
    """``text`` with the options it names in backquotes (``"`seed` 3"``) as their Python names (``seed 3``), or with
    ``flags`` as their command-line flags (``--seed 3``; ``option_flag`` of ``options``)."""
    return _MENTION.sub(lambda m: option_flag(m.group(1), options) if flags else m.group(1), text)


def _joined(problem: str) -> str:
    """``problem`` after a parameter's name: a space, none before ``:`` or ``,`` (``resume: out/runs.jsonl was made with ...``)."""
    return problem if problem.startswith((":", ",")) else f" {problem}"


class LocalizationError(SwarmError, RuntimeError):
    """Localization cannot produce a trustworthy answer for the robots in ``robots``.

    ``reason`` is a short machine-readable tag: ``"unobserved"``, ``"disconnected"``,
    ``"degenerate"`` or ``"no-convergence"``.
    """

    def __init__(self, reason: str, robots: Iterable[int], detail: str = "") -> None:
        self.reason = reason
        self.robots = sorted(int(r) for r in robots)
        message = f"{reason}: robots {self.robots}"
        super().__init__(f"{message} ({detail})" if detail else message)


class SwarmRunError(SwarmError, RuntimeError):
    """A run that started could not finish: robots lost, the run aborted or stopped (an emergency stop); ``robots``
    names the robots concerned (empty when none in particular)."""

    def __init__(self, message: str, robots: Iterable[int] = ()) -> None:
        super().__init__(message)
        self.robots = [int(r) for r in robots]


class SwarmConnectionError(SwarmError, ConnectionError):
    """A connection could not be opened, was refused or was lost: the hub (router) down or refusing this process's
    certificate, a serial device or radio that cannot be opened, a recorder that never reached the hub."""


class RunConflictError(SwarmConnectionError):
    """Another coordinator holds (or held) the run: a run has one master at a time."""


class OutputError(SwarmError):
    """An output could not be written (disk full, file size limit, permissions): the message names the file. Commands
    exit 5 for it, as a run whose recording or result failed."""


class RecordingError(OutputError, OSError):
    """A recording could not be written, or its failure stopped the run (``--on-record-error stop``)."""
