"""Command-line flags generated from an options dataclass, so each option's name, default and help are declared once.

A field of an options dataclass (``inchworm.sim_options.SimOptions``, ``inchworm.comparison.CompareOptions``, the
``inchworm.studies`` options, those of ``inchworm.launch_options``) becomes a flag: ``--`` and its name with dashes,
or its ``metadata["flag"]`` (a short flag such as ``-n`` goes before the long one), the field's default,
``metadata["help"]``, to which `` (default X)`` is added unless the help places the default itself with
``%(default)s`` or words it (``metadata["own_default"]``) or has no default to show, and ``metadata["choices"]`` and
``["metavar"]`` if declared. The annotation gives the argparse type: ``int``, ``float``, ``str``, ``Path`` (or
``StrPath``), ``bool`` (``--name`` sets True; a field that defaults to True and whose flag is ``--no-name`` sets
False) and ``tuple[int | float | str, ...]``, a comma-separated value (``--methods a,b``) that stays text in the
namespace (``--config`` files and ``study.toml`` keep it as typed) and that ``options_of`` splits (each member at
least ``metadata["minimum"]``, default 0). A union takes the flag of its one member of these types (``str |
Strategy``: a name on the command line, an object from Python). A field of another type (a nested options object: the
model, the localizer, the anchor search, added by ``swarm_cli.options``'s groups) is passed to ``add_fields`` in
``exclude`` and to ``options_of`` by name; a field with no command-line form at all is left out of both (``only``,
``keep``) and keeps the class's default. The library checks the values (``OptionError`` naming the field); the command
prints the error with the flag (``OptionError.flag_message``).

A process spec (``inchworm.specs``, a ``msgspec`` Struct) declares the command-line form of a field beside it, in its
annotation: ``Annotated[int, cli("help", ...)]`` (``inchworm.specs.cli``: ``msgspec.Meta(extra=...)``, the same keys as
a dataclass field's ``metadata``, and ``repeat``: a flag given once per member of a ``tuple[str, ...]``, and
``own_default``: the help words the default itself; ``const``: the value of the flag given without one). Only those
fields get flags; a field without a flag (the model, the anchor search, a flag whose value is converted, such as
``--id 0-4``) is made apart and passed to ``options_of`` by name, or keeps the spec's default. A field without a
default is a required flag.
"""

from __future__ import annotations

import argparse
import dataclasses
import re
from collections.abc import Callable, Collection, Mapping
from pathlib import Path
from types import NoneType, UnionType
from typing import Annotated, Any, TypeVar, Union, cast, get_args, get_origin

import msgspec

from swarm_cli.options import names, parse_list

T = TypeVar("T")
_SCALARS: dict[str, type] = {"int": int, "float": float, "str": str, "bool": bool, "Path": Path, "StrPath": Path}
_MANY = re.compile(r"^tuple\[(int|float|str), \.\.\.\]$")


@dataclasses.dataclass(frozen=True)
class Kind:
    """What a field's annotation says (``| None`` aside): its scalar type, ``many`` for a ``tuple[X, ...]``."""

    scalar: type
    many: bool = False


@dataclasses.dataclass(frozen=True)
class SpecField:
    """A field of a process spec as a dataclass field reads: its name, its annotation as text, its default (or
    ``default_factory``; ``dataclasses.MISSING``: none) and, as ``metadata``, its ``cli(...)`` declaration."""

    name: str
    type: str
    default: Any = dataclasses.MISSING
    default_factory: Any = dataclasses.MISSING
    metadata: Mapping[str, Any] = dataclasses.field(default_factory=dict)


def _text(tp: Any) -> str:
    """An annotation as text (``Annotated`` dropped): ``str | None``, ``tuple[str, ...]``, ``int``."""
    if get_origin(tp) is Annotated:
        return _text(get_args(tp)[0])
    if get_origin(tp) in (Union, UnionType):
        return " | ".join(map(_text, get_args(tp)))
    if tp is NoneType:
        return "None"
    if get_origin(tp) is tuple and len(get_args(tp)) == 2 and get_args(tp)[1] is Ellipsis:
        return f"tuple[{_text(get_args(tp)[0])}, ...]"
    return tp.__name__ if isinstance(tp, type) and get_origin(tp) is None else str(tp)


def _declared(tp: Any) -> Mapping[str, Any] | None:
    """The ``cli(...)`` declaration of an annotation (None: the field has no flag)."""
    if get_origin(tp) is Annotated:
        for meta in get_args(tp)[1:]:
            if isinstance(meta, msgspec.Meta) and meta.extra is not None:
                return meta.extra
    return None


def spec_fields(cls: type) -> list[SpecField]:
    """The fields of the process spec ``cls`` that declare a flag."""
    found = []
    for f in msgspec.structs.fields(cls):
        declared = _declared(f.type)
        if declared is not None:
            found.append(SpecField(f.name, _text(f.type), dataclasses.MISSING if f.default is msgspec.NODEFAULT else f.default,
                                   dataclasses.MISSING if f.default_factory is msgspec.NODEFAULT else f.default_factory, declared))
    return found


def _fields(cls: type) -> list[Any]:
    """The fields of an options dataclass, or those of a process spec that declare a flag."""
    return spec_fields(cls) if issubclass(cls, msgspec.Struct) else list(dataclasses.fields(cast(Any, cls)))


def _required(f: Any) -> bool:
    return f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING


def _members(text: str) -> list[str]:
    """The members of a union's annotation text, split at its top level (not inside ``tuple[...]``)."""
    parts, depth, start = [], 0, 0
    for i, char in enumerate(text):
        depth += (char == "[") - (char == "]")
        if char == "|" and depth == 0:
            parts.append(text[start:i].strip())
            start = i + 1
    return [*parts, text[start:].strip()]


def _kind(text: str) -> Kind | None:
    if text in _SCALARS:
        return Kind(_SCALARS[text])
    many = _MANY.match(text)
    return Kind(_SCALARS[many.group(1)], many=True) if many else None


def kind_of(f: dataclasses.Field[Any] | SpecField) -> Kind | None:
    """The ``Kind`` of a field's annotation (a string under ``from __future__ import annotations``): of its one member
    with a flag type (``None`` aside), None if it has no such member or several."""
    text = f.type if isinstance(f.type, str) else getattr(f.type, "__name__", str(f.type))
    kinds = [k for k in map(_kind, _members(text)) if k is not None]
    return kinds[0] if len(kinds) == 1 else None


def flag_of(f: dataclasses.Field[Any] | SpecField) -> str:
    """A field's flag: ``metadata["flag"]``, else ``--`` and its name with dashes (as ``OptionError.flag``)."""
    return str(f.metadata.get("flag", "--" + f.name.replace("_", "-")))


def default_of(f: dataclasses.Field[Any] | SpecField) -> Any:
    """A field's default as the command line takes it: a tuple as comma-separated text (``0.5,1,2,4``), a repeated
    flag's as a list (None: a required flag)."""
    if _required(f):
        return None
    if f.metadata.get("repeat"):
        return []
    value = f.default_factory() if f.default is dataclasses.MISSING and f.default_factory is not dataclasses.MISSING else f.default
    if isinstance(value, tuple):
        return ",".join(f"{v:g}" if isinstance(v, float) else str(v) for v in value)
    return value


def _shown(value: Any) -> str:
    return f"{value:g}" if isinstance(value, float) else str(value)


def _negated(f: dataclasses.Field[Any] | SpecField) -> bool:
    """A True-by-default switch whose flag (``--no-name``) turns it off."""
    return f.default is True and flag_of(f).startswith("--no-")


def dest_of(f: dataclasses.Field[Any] | SpecField) -> str:
    """Where the field's value lands in the namespace: its name, or for ``--no-name`` switches ``no_name``."""
    return flag_of(f).removeprefix("--").replace("-", "_") if _negated(f) else f.name


def option_fields(cls: type, exclude: Collection[str] = (), only: Collection[str] | None = None) -> list[Any]:
    """The fields of the dataclass ``cls`` that have flags (``only`` those, none of ``exclude``; of a process spec: those
    that declare one); ``TypeError`` for a field whose type has no flag and that is not excluded (a new field must get a
    flag or be added elsewhere), or a switch that defaults to True without a ``--no-name`` flag (a ``--name`` switch
    could only set what it is already)."""
    chosen = [f for f in _fields(cls) if f.name not in exclude and (only is None or f.name in only)]
    missing = [f.name for f in chosen if kind_of(f) is None or (f.default is True and not _negated(f))]
    if missing:
        raise TypeError(f"{cls.__name__}: fields {missing} have no command-line form (a type without one, or a switch on by default "
                        "without a --no-name flag): exclude them and add their options apart")
    return chosen


def add_fields(parser: argparse._ActionsContainer, cls: type, *, exclude: Collection[str] = (), only: Collection[str] | None = None,
               types: Mapping[str, Callable[[str], Any]] | None = None) -> None:
    """Add a flag to ``parser`` for every field of the options dataclass ``cls`` (module doc); ``types`` overrides the
    argparse type of some (e.g. ``positive_int``, so argparse refuses the value as it is typed)."""
    for f in option_fields(cls, exclude, only):
        kind = kind_of(f)
        assert kind is not None  # option_fields refused the others
        flag, default = flag_of(f), default_of(f)
        strings = [flag, "--" + f.name.replace("_", "-")] if not flag.startswith("--") else [flag]
        text = str(f.metadata.get("help", ""))
        if "%(default)s" in text:
            text = text.replace("%(default)s", _shown(default))
        elif default is not None and not isinstance(default, (bool, list)) and not f.metadata.get("own_default"):
            text = f"{text} (default {_shown(default)})"
        extra: dict[str, Any] = {key: f.metadata[key] for key in ("metavar", "choices", "const") if key in f.metadata}
        if "const" in extra:  # the flag alone gives ``const``
            extra["nargs"] = "?"
        if _required(f):
            extra["required"] = True
        if kind.scalar is bool and not kind.many:
            parser.add_argument(*strings, dest=dest_of(f), action="store_true", help=text)
        elif f.metadata.get("repeat"):
            parser.add_argument(*strings, dest=f.name, action="append", default=[], help=text, **extra)
        else:
            convert = (types or {}).get(f.name, str if kind.many else kind.scalar)
            parser.add_argument(*strings, dest=f.name, type=convert, default=default, help=text, **extra)


def value_of(args: argparse.Namespace, f: dataclasses.Field[Any] | SpecField) -> Any:
    """The field's value from the namespace: a comma-separated text split (numbers checked, naming the flag), a
    repeated flag's values a tuple."""
    value = getattr(args, dest_of(f))
    kind = kind_of(f)
    if _negated(f):
        return not value
    if f.metadata.get("repeat"):
        return tuple(value)
    if kind is None or not kind.many or value is None:
        return value
    if kind.scalar is str:
        return names(value)
    return tuple(parse_list(value, flag_of(f), kind.scalar, f.metadata.get("minimum", 0)))


def options_of(args: argparse.Namespace, cls: Callable[..., T], *, keep: Collection[str] = (), **given: Any) -> T:
    """The options dataclass (or process spec) ``cls`` made from the namespace: every field with a flag from its value,
    the others from ``given`` (``run=run_options(args)``); the fields ``keep`` (no command-line form) keep the class's
    defaults (a spec's fields without a flag keep theirs unless given)."""
    values = {f.name: value_of(args, f) for f in option_fields(cast(type, cls), exclude={*given, *keep})}
    return cls(**values, **given)
