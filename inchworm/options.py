"""Options shared by the comparison and the studies: the model, the localizer and the anchor search."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields
from typing import TYPE_CHECKING, Any

from coordinator.localization.registry import DEFAULT_LOCALIZER, localizer_names
from runtime.errors import SwarmInputError
from runtime.models.config import ModelConfig

if TYPE_CHECKING:
    from coordinator.selection.selector import SelectionConfig



def default_selection() -> SelectionConfig:
    from coordinator.selection.selector import SelectionConfig  # noqa: PLC0415 - scipy only when a study runs

    return SelectionConfig()


@dataclass(frozen=True)
class RunOptions:
    """How every run of a study simulates: noise and sensing (``model``), localizer and anchor search."""

    model: ModelConfig = field(default_factory=ModelConfig)
    localizer: str = DEFAULT_LOCALIZER  # a registered name (``coordinator.localization.registry``)
    selection: SelectionConfig = field(default_factory=default_selection)


def check_localizers(localizers: tuple[str, ...], flag: str = "localizers") -> None:
    known = localizer_names()
    if not localizers or any(x not in known for x in localizers):
        raise SwarmInputError(f"--{flag} must list localizers among {', '.join(known)}, got {','.join(localizers)!r}")


def check_at_least(flag: str, value: int, low: int) -> None:
    if value < low:
        raise SwarmInputError(f"--{flag} must be >= {low}, got {value}")


def options_dict(options: Any) -> dict[str, Any]:
    """The options as plain JSON-ready values (what a study log keeps to check ``resume``)."""
    out = {}
    for f in fields(options):
        value = getattr(options, f.name)
        out[f.name] = asdict(value) if hasattr(value, "__dataclass_fields__") else value
    return out
