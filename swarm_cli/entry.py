"""How every ``swarm`` command turns user errors into a message and an exit code (no tracebacks)."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable

from runtime.errors import LocalizationError, SwarmInputError


def guarded(prog: str, run: Callable[[], int | None]) -> int:
    """``run()``'s exit code; bad input or I/O errors print ``prog: error: ...`` and give 2, Ctrl-C gives 130."""
    try:
        return int(run() or 0)
    except (SwarmInputError, LocalizationError, OSError) as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130


def run_standalone(
    prog: str,
    add_arguments: Callable[[argparse.ArgumentParser], None],
    run: Callable[[argparse.Namespace], int | None],
    argv: list[str] | None = None,
) -> int:
    """Entry point of a command started as its own module (``python -m swarm_cli.agent``):
    the launcher starts processes this way so each imports only what it needs."""
    parser = argparse.ArgumentParser(prog=prog)
    add_arguments(parser)
    args = parser.parse_args(argv)
    return guarded(prog, lambda: run(args))
