"""Exceptions with messages that name what is wrong (robot ids, fields, files)."""

from __future__ import annotations

from collections.abc import Iterable


class SwarmError(Exception):
    """Base of every error the runtime raises on purpose (catch this one to catch them all)."""


class SwarmInputError(SwarmError, ValueError):
    """Bad user input: malformed values, NaN/inf, unknown ids, impossible requests."""


class OutputError(SwarmError):
    """An output could not be written (disk full, file size limit, permissions): the message names the file. Commands
    exit 5 for it, as a run whose recording or result failed."""


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
