"""Path arguments: every path the library takes may be a ``str`` or any ``os.PathLike`` (``StrPath``)."""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import TypeAlias, overload

StrPath: TypeAlias = str | os.PathLike[str]


@overload
def as_path(value: StrPath) -> Path: ...
@overload
def as_path(value: None) -> None: ...
def as_path(value: StrPath | None) -> Path | None:
    """``value`` as a ``Path`` (``None`` stays ``None``)."""
    return None if value is None else Path(value)


def coerce_paths(options: object, *names: str) -> None:
    """In a (frozen) dataclass's ``__post_init__``: its fields ``names`` as ``Path`` (given as ``str`` or ``os.PathLike``)."""
    for name in names:
        value = getattr(options, name)
        if value is not None and not isinstance(value, Path):
            object.__setattr__(options, name, Path(value))
    assert dataclasses.is_dataclass(options), "options dataclasses only"
