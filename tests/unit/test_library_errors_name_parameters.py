"""Library errors name Python parameters, never command-line flags: the command line translates an ``OptionError``'s
parameter (and the options its problem names in backquotes) into flags (``OptionError.flag_message``). Every string
literal of a ``raise`` statement in the library packages is read from the sources (``ast``); one that names a flag
(``--name``, also ``--{...}`` built in an f-string) fails here unless it is allowed below with its reason."""

from __future__ import annotations

import ast
import functools
import re
from pathlib import Path

import pytest

from runtime.errors import OptionError

ROOT = Path(__file__).resolve().parents[2]
LIBRARY = ("inchworm", "coordinator", "runtime", "robot_agent")
FLAG = re.compile(r"--[a-z{]")
# (file, a piece of the message): why it may name a command line
ALLOWED = {
    ("runtime/recording/ros2_export.py", "swarm export --ros2 needs rosbags"):
        "the optional dependency is named with the command that needs it, as every other install hint names its command",
}


def _texts(node: ast.expr) -> list[str]:
    """The string literals of an expression; an f-string as its literal parts with ``{}`` for each value."""
    out = []
    for sub in ast.walk(node):
        if isinstance(sub, ast.JoinedStr):
            out.append("".join(str(v.value) if isinstance(v, ast.Constant) else "{}" for v in sub.values))
        elif isinstance(sub, ast.Constant) and isinstance(sub.value, str):
            out.append(sub.value)
    return out


@functools.cache
def _flagged() -> tuple[tuple[str, int, str], ...]:
    found: list[tuple[str, int, str]] = []
    for package in LIBRARY:
        for path in sorted((ROOT / package).rglob("*.py")):
            name = path.relative_to(ROOT).as_posix()
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                if isinstance(node, ast.Raise) and node.exc is not None:
                    found += [(name, node.lineno, text) for text in _texts(node.exc) if FLAG.search(text)]
    return tuple(found)


def test_no_library_error_names_a_flag() -> None:
    flagged = [(name, line, text) for name, line, text in _flagged()
               if not any(name == file and piece in text for file, piece in ALLOWED)]
    assert flagged == [], "\n".join(f"{name}:{line}: {text!r}: name the parameter (OptionError), not the flag" for name, line, text in flagged)


def test_every_allowed_message_still_exists() -> None:
    texts = {(name, text) for name, _line, text in _flagged()}
    stale = [key for key in ALLOWED if not any(name == key[0] and key[1] in text for name, text in texts)]
    assert stale == []


def test_the_scan_sees_flags_in_f_strings_and_multi_line_raises() -> None:
    tree = ast.parse('def f(name):\n    raise ValueError(\n        f"--{name} must be >= 1"\n        " or not"\n    )\n')
    raise_node = next(n for n in ast.walk(tree) if isinstance(n, ast.Raise))
    assert raise_node.exc is not None and [t for t in _texts(raise_node.exc) if FLAG.search(t)] == ["--{} must be >= 1 or not"]


@pytest.mark.parametrize(("error", "library", "command_line"), [
    (OptionError("driver", "sim needs `pose` or `trajectory` FILE"), "driver sim needs pose or trajectory FILE",
     "--driver sim needs --pose or --trajectory FILE"),
    (OptionError("physics_params", ", `run_id` and `hub` need `world` physics", {"run_id": "--run", "physics_params": "--physics-param"}),
     "physics_params, run_id and hub need world physics", "--physics-param, --run and --hub need --world physics"),
    (OptionError("link", ": run `swarm link` for it"), "link: run `swarm link` for it", "--link: run `swarm link` for it"),
])
def test_an_option_error_names_parameters_and_its_flag_message_flags(error: OptionError, library: str, command_line: str) -> None:
    assert str(error) == library and error.flag_message() == command_line
