"""How every ``swarm`` command turns user errors into a message and an exit code (no tracebacks)."""

from __future__ import annotations

import argparse
import importlib
import os
import re
import typing
from collections.abc import Callable, Sequence
from typing import NamedTuple, TypeVar

from inchworm.entry import (  # re-exported: the commands import them from here
    EXIT_CODES as EXIT_CODES,
    EXIT_CONFLICT as EXIT_CONFLICT,
    EXIT_INPUT as EXIT_INPUT,
    EXIT_OUTPUT as EXIT_OUTPUT,
    EXIT_RUN as EXIT_RUN,
    cli_message as cli_message,
    exit_code as exit_code,
    guarded as guarded,
    leave as leave,
    limit_blas_threads as limit_blas_threads,
    on_stop_signals as on_stop_signals,
)


def plain(doc: str | None) -> str:
    """A module docstring as ``--help`` text: reStructuredText literals (````x````) and ``::`` markers removed."""
    text = re.sub(r"``([^`]+)``", r"\1", doc or "")
    return re.sub(r"::$", ":", text, flags=re.MULTILINE).strip()


def library_doc(module: str) -> str:
    """The docstring of ``module`` as ``--help`` text, read from its source without importing it."""
    import ast  # noqa: PLC0415
    import importlib.util  # noqa: PLC0415

    spec = importlib.util.find_spec(module)
    source = open(spec.origin, encoding="utf-8").read() if spec and spec.origin else ""
    return plain(ast.get_docstring(ast.parse(source)) if source else "")


class OneLineParser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose errors are one line (``prog: error: ...``) without the usage block before them;
    its subparsers are of the same class (argparse's ``add_subparsers`` default)."""

    def error(self, message: str) -> typing.NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


Parser = TypeVar("Parser", bound=argparse.ArgumentParser)  # the class of the parsers ``sub`` makes (``OneLineParser``)


class Command(NamedTuple):
    """A subcommand: its name, the module whose ``register(sub)`` adds it, and its one-line help."""

    name: str
    module: str
    help: str


def add_commands(sub: argparse._SubParsersAction[Parser], commands: Sequence[Command], argv: Sequence[str], *, full: bool = False) -> None:
    """Register ``commands`` on ``sub``, importing only the module of the one ``argv`` names.

    The command named by the first positional word of ``argv`` (every command with ``full``)
    is registered by its module's ``register(sub)``; the others get a parser with their help
    line only, enough for ``--help`` and for argparse's "invalid choice" message. A module
    with ``NESTED = True`` (``swarm bench``, ``swarm study``) gets ``register(sub, argv=rest,
    full=full)`` to do the same one level down. Nothing heavy is imported to build a parser.
    """
    chosen = next((i for i, a in enumerate(argv) if not a.startswith("-")), None)
    name = argv[chosen] if chosen is not None else None
    wanted = {c.module for c in commands if full or c.name == name}
    done: set[str] = set()
    for c in commands:
        if c.module in wanted:
            if c.module not in done:
                done.add(c.module)
                module = importlib.import_module(c.module)
                if getattr(module, "NESTED", False):
                    module.register(sub, argv=list(argv[chosen + 1:]) if chosen is not None and not full else [], full=full)
                else:
                    module.register(sub)
        else:
            sub.add_parser(c.name, help=c.help)


def run_standalone(
    prog: str,
    add_arguments: Callable[[argparse.ArgumentParser], None],
    run: Callable[[argparse.Namespace], int | None],
    argv: list[str] | None = None,
) -> int:
    """Entry point of a command started as its own module (``python -m swarm_cli.agent``):
    the launcher starts processes this way so each imports only what it needs."""
    from inchworm.lifeline import hold_lifeline  # noqa: PLC0415

    hold_lifeline()  # started by a launcher: end with it, whatever killed it
    limit_blas_threads()
    parser = OneLineParser(prog=prog)
    add_arguments(parser)
    args = parser.parse_args(argv)
    return guarded(prog, lambda: run(args))


def portable_command(prog: str, args: Sequence[str]) -> str:
    """``prog`` and ``args`` as one line for a recording's metadata, absolute paths cut to their file name
    (``--trajectory=/tmp/x/trajectory.json`` -> ``--trajectory=trajectory.json``): recordings are shared,
    and a machine's folder layout is neither portable nor anybody else's business."""
    def cut(value: str) -> str:
        return os.path.basename(value.rstrip("/")) or value if os.path.isabs(value) else value

    words = []
    for arg in args:
        name, sep, value = arg.partition("=")
        words.append(f"{name}={cut(value)}" if sep and name.startswith("--") else cut(arg))
    return " ".join([prog, *words])
