"""Options shared by the comparison and the studies: the model, the localizer and the anchor search."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, fields
from typing import TYPE_CHECKING, Any

from coordinator.localization.registry import DEFAULT_LOCALIZER, localizer_names
from runtime.errors import OptionError
from runtime.models.config import ModelConfig

if TYPE_CHECKING:
    from coordinator.selection.selector import SelectionConfig



def default_selection() -> SelectionConfig:
    from coordinator.selection.selector import SelectionConfig  # noqa: PLC0415 - scipy only when a study runs

    return SelectionConfig()


@dataclass(frozen=True, kw_only=True)
class RunOptions:
    """How every run of a study simulates: noise and sensing (``model``), localizer and anchor search."""

    model: ModelConfig = field(default_factory=ModelConfig)
    localizer: str = DEFAULT_LOCALIZER  # a registered name (``coordinator.localization.registry``)
    selection: SelectionConfig = field(default_factory=default_selection)

    def __post_init__(self) -> None:
        check_localizers(self, "localizer")


def check_localizers(options: Any, name: str = "localizers") -> None:
    """``OptionError`` unless the option ``name`` of ``options`` (a name or a tuple of names) lists registered localizers."""
    value = getattr(options, name)
    given = (value,) if isinstance(value, str) else tuple(value)
    known = localizer_names()
    if not given or any(x not in known for x in given):
        what = "be one of the localizers" if isinstance(value, str) else "list localizers among"
        raise OptionError(name, f"must {what} {', '.join(known)}, got {','.join(given)!r}", options)


def check_at_least(options: Any, name: str, low: float) -> None:
    """``OptionError`` unless the option ``name`` of ``options`` is >= ``low``."""
    value = getattr(options, name)
    if value < low:
        raise OptionError(name, f"must be >= {low}, got {value}", options)


def check_among(options: Any, name: str, known: tuple[str, ...]) -> None:
    """``OptionError`` unless the option ``name`` of ``options`` lists names of ``known`` only (at least one)."""
    given = tuple(getattr(options, name))
    unknown = [x for x in given if x not in known]
    if unknown or not given:
        raise OptionError(name, f"must list names among {', '.join(known)}; " + (f"unknown: {unknown}" if unknown else "got none"), options)


def check_numbers(options: Any, name: str, low: float = 0.0, *, above: bool = False) -> None:
    """``OptionError`` unless the option ``name`` of ``options`` lists finite numbers >= ``low`` (``above``: > ``low``)."""
    values = tuple(getattr(options, name))
    if not values or not all(math.isfinite(v) and (v > low if above else v >= low) for v in values):
        raise OptionError(name, f"must list numbers {'>' if above else '>='} {low:g}, got {list(values)}", options)


def options_dict(options: Any) -> dict[str, Any]:
    """The options as plain JSON-ready values (what a study log keeps to check ``resume``)."""
    out = {}
    for f in fields(options):
        value = getattr(options, f.name)
        out[f.name] = asdict(value) if hasattr(value, "__dataclass_fields__") else value
    return out


def call_keywords(function: str, cls: type, given: object, first: str, names: tuple[str, ...], args: tuple[Any, ...],
                  keywords: dict[str, Any]) -> dict[str, Any] | None:
    """The keywords of a library function that takes its options object (``cls``) or its ``first`` argument, then
    ``names`` positionally or as keywords: None when ``given`` is the options object (a ``TypeError`` with arguments
    beside it), else ``first`` and the arguments by name (a ``TypeError`` for too many, or one given twice)."""
    if isinstance(given, cls):
        if args or keywords:
            raise TypeError(f"{function}() takes {cls.__name__} or the {first} and keywords, not both: "
                            "dataclasses.replace(options, ...) changes some")
        return None
    if len(args) > len(names):
        raise TypeError(f"{function}() takes at most {1 + len(names)} positional arguments ({', '.join((first, *names))}), "
                        f"got {1 + len(args)}")
    named = dict(zip(names, args, strict=False))
    twice = sorted(set(named) & set(keywords))
    if twice:
        raise TypeError(f"{function}() got {', '.join(twice)} twice: as positional and keyword arguments")
    return {first: given, **named, **keywords}
