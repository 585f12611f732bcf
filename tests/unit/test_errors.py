"""One error hierarchy (runtime.errors): every error raised to a user is a ``SwarmError``, run failures are not input
errors, and the exit code of every command maps from the class in one place (``inchworm.entry.exit_code``)."""

from __future__ import annotations

import ast
import builtins
import dataclasses
import pickle
from pathlib import Path

import pytest

from coordinator.executor import RunAborted
from coordinator.node.process import RecordingStopped
from coordinator.node.zenoh_backend import AgentError, AgentLost, CoordinatorConflict, HubLost, RunStopped, SteppedDown
from robot_agent.driver import DriverFault, DriverRefused, RobotLost
from runtime.errors import (
    LocalizationError,
    OptionError,
    OutputError,
    RecordingError,
    RunConflictError,
    SwarmConnectionError,
    SwarmError,
    SwarmInputError,
    SwarmRunError,
)
from runtime.gateway.frames import FrameError
from runtime.recording.mcap_log import RecordingFailed
from runtime.wire.messages import MessageError
from swarm_cli.entry import guarded

ROOT = Path(__file__).resolve().parents[2]
BUILTIN = {name for name, value in vars(builtins).items() if isinstance(value, type) and issubclass(value, BaseException)}
# not errors of ours: a mixin whose raised subclasses are SwarmErrors, a bench's own loop exit, a stop signal (a
# KeyboardInterrupt), the stand-in of an optional dependency's exception
NOT_OURS = {"BackendEnded", "EnoughSteps", "StopRequested", "_ZstdError"}


def test_no_error_class_outside_the_hierarchy():
    """Only runtime/errors.py derives from a built-in exception; every other error class derives from one of its."""
    outside = []
    for package in ("runtime", "coordinator", "robot_agent", "inchworm", "swarm_cli"):
        for path in (ROOT / package).rglob("*.py"):
            if path == ROOT / "runtime" / "errors.py":
                continue
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                if isinstance(node, ast.ClassDef) and node.name not in NOT_OURS and \
                        any(isinstance(b, ast.Name) and b.id in BUILTIN for b in node.bases):
                    outside.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.name}")
    assert outside == []


@pytest.mark.parametrize("error", [AgentError("x", [1]), AgentLost("x", [1]), RunStopped("x", []), HubLost("x"),
                                   RunAborted("x", [2]), RobotLost("x"), DriverFault("x"), DriverRefused("x")])
def test_run_failures_are_run_errors_not_input_errors(error):
    assert isinstance(error, SwarmRunError) and not isinstance(error, SwarmInputError)


def test_the_kinds_keep_their_builtin_bases():
    assert issubclass(SwarmInputError, ValueError) and issubclass(FrameError, SwarmInputError)
    assert issubclass(SwarmConnectionError, ConnectionError) and issubclass(HubLost, SwarmConnectionError)
    assert issubclass(CoordinatorConflict, RunConflictError) and issubclass(SteppedDown, CoordinatorConflict)
    assert issubclass(RecordingFailed, RecordingError) and issubclass(RecordingFailed, OSError)
    assert issubclass(RecordingStopped, RecordingError) and issubclass(RecordingError, OutputError)
    assert RunAborted("x", [2, 3]).robots == [2, 3] and AgentLost("x", [4]).robots == [4]


@pytest.mark.parametrize("error, code", [
    (SwarmInputError("x"), 2), (OptionError("trajectories", "must be >= 1, got 0"), 2), (LocalizationError("unobserved", [1]), 2),
    (SwarmConnectionError("x"), 2), (FileNotFoundError(2, "No such file"), 2),
    (AgentLost("x", [1]), 3), (RunAborted("x", [1]), 3), (RunStopped("x", []), 3), (HubLost("x"), 3),
    (CoordinatorConflict("x"), 4), (SteppedDown("x"), 4),
    (OutputError("x"), 5), (RecordingStopped("x"), 5), (RecordingFailed(Path("r.mcap"), OSError(28, "No space left"), 3, 1), 5),
])
def test_every_exit_code_comes_from_the_class(error, code, capsys):
    def fail() -> int:
        raise error
    assert guarded("swarm x", fail) == code
    assert capsys.readouterr().err.startswith("swarm x: error: ")


def test_a_bug_is_not_a_users_error():
    with pytest.raises(KeyError):
        guarded("swarm x", lambda: {}["missing"])


@dataclasses.dataclass(frozen=True)
class Options:
    robots: int = dataclasses.field(default=10, metadata={"flag": "-n"})
    min_robots: int = 2


def test_option_errors_name_the_parameter_and_the_cli_the_flag(capsys):
    error = OptionError("robots", "must be >= 2, got 1", Options())
    assert str(error) == "robots must be >= 2, got 1" and error.parameter == "robots"
    assert error.flag_message() == "-n must be >= 2, got 1"
    assert OptionError("min_robots", "must be >= 2", Options()).flag_message() == "--min-robots must be >= 2"

    def fail() -> int:
        raise error
    assert guarded("swarm x", fail) == 2
    assert capsys.readouterr().err == "swarm x: error: -n must be >= 2, got 1\n"
    assert isinstance(error, SwarmError)


# an instance of every error class with an __init__ of its own (and of the classes that inherit one), with rough values
BUILT = [
    OptionError("driver", "sim needs `pose` or `trajectory` FILE", Options()), OptionError("robots", "must be >= 2", {"robots": "-n"}),
    MessageError("ObservationReport.ranges[3]", "is NaN", "invalid"), LocalizationError("disconnected", [3, 1], "two components"),
    SwarmRunError("robots lost", [2, 5]), AgentError("x", [1]), AgentLost("not alive", [0, 7]), RunStopped("stopped", []),
    HubLost("hub gone"), RunAborted("fewer than 2 robots left", [4], None), DriverRefused("refused", [9]), RobotLost("gone"),
    DriverFault("fault", [1]), RecordingFailed(Path("r.mcap"), OSError(28, "No space left on device"), 3, 1),
    SteppedDown("taken over"), CoordinatorConflict("two masters"), RecordingStopped("stopped"), FrameError("bad frame"),
]


def _own_inits() -> set[str]:
    """The names of the SwarmError classes of the packages that define an ``__init__`` or inherit one (from the sources)."""
    bases: dict[str, list[str]] = {}
    inits: set[str] = set()
    for package in ("runtime", "coordinator", "robot_agent", "inchworm", "swarm_cli"):
        for path in (ROOT / package).rglob("*.py"):
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                if isinstance(node, ast.ClassDef):
                    bases[node.name] = [b.id for b in node.bases if isinstance(b, ast.Name)]
                    if any(isinstance(f, ast.FunctionDef) and f.name == "__init__" for f in node.body):
                        inits.add(node.name)

    def ours(name: str, seen: frozenset[str] = frozenset()) -> bool:
        return name == "SwarmError" or (name not in seen and any(ours(b, seen | {name}) for b in bases.get(name, ())))

    def has_init(name: str) -> bool:
        return name in inits or any(has_init(b) for b in bases.get(name, ()) if b != "SwarmError")
    return {name for name in bases if name != "SwarmError" and ours(name) and has_init(name)}


def test_every_error_with_its_own_init_is_round_tripped_below():
    assert _own_inits() <= {type(e).__name__ for e in BUILT}


@pytest.mark.parametrize("error", BUILT, ids=lambda e: type(e).__name__)
def test_errors_survive_pickling(error):
    """An error raised in a process-pool worker comes back whole: its class, message, args and attributes."""
    back = pickle.loads(pickle.dumps(error))
    assert type(back) is type(error) and str(back) == str(error) and back.args == error.args
    assert set(vars(back)) == set(vars(error))
    for name, value in vars(error).items():
        assert repr(getattr(back, name)) == repr(value), name
    if isinstance(error, OptionError):
        assert back.flag_message() == error.flag_message()
