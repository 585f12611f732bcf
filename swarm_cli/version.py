"""``swarm --version``: the installed distribution's version, read from its metadata only when asked."""

from __future__ import annotations

import argparse
import sys
from typing import NoReturn

DISTRIBUTION = "inchworm-swarm"


def installed_version() -> str:
    """The version of the installed ``inchworm-swarm`` distribution (``importlib.metadata``)."""
    from importlib.metadata import PackageNotFoundError, version  # noqa: PLC0415 - ~40 ms that --help need not pay

    try:
        return version(DISTRIBUTION)
    except PackageNotFoundError:
        return "unknown (not installed: pip install -e .)"


class VersionAction(argparse.Action):
    """Like argparse's ``version`` action, but the version is looked up when the flag is given."""

    def __init__(self, option_strings: list[str], dest: str = argparse.SUPPRESS, default: str = argparse.SUPPRESS,
                 help: str = "print the installed version and exit") -> None:
        super().__init__(option_strings=option_strings, dest=dest, default=default, nargs=0, help=help)

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: object,
                 option_string: str | None = None) -> NoReturn:
        sys.stdout.write(f"{parser.prog} {installed_version()}\n")
        parser.exit()
