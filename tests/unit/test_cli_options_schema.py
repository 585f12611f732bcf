"""The flags of the commands whose options are dataclasses come from those dataclasses (``swarm_cli.schema``): every
field has its flag (or is made by a shared group of options), and the command line's defaults make the dataclass's
defaults, so a new field without a flag or a flag whose default drifts from the field's fails here."""

from __future__ import annotations

import argparse
import dataclasses
import importlib
from collections.abc import Callable
from typing import Any

import pytest

from runtime.errors import OptionError, SwarmInputError
from swarm_cli.main import build_parser
from swarm_cli.schema import add_fields, default_of, flag_of, option_fields, options_of

# command, the module whose options(args) makes the options, the options class, the fields that shared groups make
COMMANDS = [
    ("compare", "swarm_cli.compare", "inchworm.comparison:CompareOptions", ("run",)),
    ("study anchors", "swarm_cli.study_anchors", "inchworm.studies.anchors:AnchorsOptions", ("model", "localizer")),
    ("study noise", "swarm_cli.study_noise", "inchworm.studies.noise:NoiseOptions", ("run",)),
    ("study consistency", "swarm_cli.study_consistency", "inchworm.studies.consistency:ConsistencyOptions", ("model", "selection")),
    ("study selection", "swarm_cli.study_selection", "inchworm.studies.selection:SelectionStudyOptions", ("run",)),
    ("study calibration", "swarm_cli.study_calibration", "inchworm.studies.calibration:CalibrationOptions", ("run",)),
]


def _subparser(argv: list[str]) -> argparse.ArgumentParser:
    parser = build_parser(argv)
    for word in argv:
        sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        parser = sub.choices[word]
    return parser


def _class(path: str) -> type:
    module, name = path.split(":")
    cls: type = getattr(importlib.import_module(module), name)
    return cls


@pytest.mark.parametrize(("command", "module", "path", "shared"), COMMANDS, ids=[c[0] for c in COMMANDS])
def test_every_field_is_a_flag_with_the_fields_default(command: str, module: str, path: str, shared: tuple[str, ...]) -> None:
    cls, parser = _class(path), _subparser(command.split())
    actions = {s: a for a in parser._actions for s in a.option_strings}
    for f in option_fields(cls, exclude=shared):
        action = actions.get(flag_of(f))
        assert action is not None, f"swarm {command}: field {f.name} has no flag {flag_of(f)}"
        if action.nargs != 0:  # a switch's default is its field's (checked below)
            assert action.default == default_of(f), f"swarm {command} {flag_of(f)}: default {action.default!r}, field {default_of(f)!r}"
        assert action.help and "help" in f.metadata, f"swarm {command} {flag_of(f)}: no help declared on the field"
    made: Callable[[argparse.Namespace], Any] = importlib.import_module(module).options
    assert made(parser.parse_args([])) == cls()  # the shared groups' defaults too


@dataclasses.dataclass(frozen=True)
class Toy:
    size: int = dataclasses.field(default=3, metadata={"help": "how many", "flag": "-s"})
    scales: tuple[float, ...] = dataclasses.field(default=(0.5, 2.0), metadata={"help": "factors (default %(default)s; any > 0)"})
    names: tuple[str, ...] | None = dataclasses.field(default=None, metadata={"help": "names"})
    optimum: bool = dataclasses.field(default=True, metadata={"help": "skip it", "flag": "--no-optimum"})
    quick: bool = dataclasses.field(default=False, metadata={"help": "be quick"})

    def __post_init__(self) -> None:
        if self.size < 1:
            raise OptionError("size", f"must be >= 1, got {self.size}", self)


def _toy() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="toy")
    add_fields(parser, Toy)
    return parser


def test_a_declaration_makes_flags_defaults_and_help() -> None:
    parser = _toy()
    helps = {a.option_strings[-1]: a.help for a in parser._actions if a.option_strings}
    assert helps["--size"] == "how many (default 3)"
    assert helps["--scales"] == "factors (default 0.5,2; any > 0)"
    assert helps["--names"] == "names"  # no default to show
    assert options_of(parser.parse_args([]), Toy) == Toy()
    given = options_of(parser.parse_args(["-s", "7", "--scales", "1,0.25", "--names", "a, b", "--no-optimum", "--quick"]), Toy)
    assert given == Toy(7, (1.0, 0.25), ("a", "b"), False, True)


def test_the_library_names_the_field_and_the_command_line_its_flag() -> None:
    with pytest.raises(OptionError) as caught:
        options_of(_toy().parse_args(["--size", "0"]), Toy)
    assert str(caught.value) == "size must be >= 1, got 0"
    assert caught.value.flag_message() == "-s must be >= 1, got 0"
    with pytest.raises(SwarmInputError, match="^--scales must list numbers >= 0, got '1,-2'$"):  # split by the command line
        options_of(_toy().parse_args(["--scales", "1,-2"]), Toy)


def test_a_field_without_a_command_line_type_must_be_excluded() -> None:
    @dataclasses.dataclass(frozen=True)
    class Nested:
        toy: Toy = dataclasses.field(default_factory=Toy)
        count: int = 1

    with pytest.raises(TypeError, match="toy"):
        add_fields(argparse.ArgumentParser(), Nested)
    parser = argparse.ArgumentParser()
    add_fields(parser, Nested, exclude=("toy",))
    assert options_of(parser.parse_args(["--count", "2"]), Nested, toy=Toy(5)) == Nested(Toy(5), 2)
