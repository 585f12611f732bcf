"""How every ``swarm`` command turns user errors into a message and an exit code (no tracebacks)."""

from __future__ import annotations

import argparse
import importlib
import os
import contextlib
import re
import signal
import sys
from collections.abc import Callable, Iterator, Sequence
from typing import NamedTuple

from runtime.errors import LocalizationError, SwarmInputError


def plain(doc: str | None) -> str:
    """A module docstring as ``--help`` text: reStructuredText literals (````x````) and ``::`` markers removed."""
    text = re.sub(r"``([^`]+)``", r"\1", doc or "")
    return re.sub(r"::$", ":", text, flags=re.MULTILINE).strip()


class Command(NamedTuple):
    """A subcommand: its name, the module whose ``register(sub)`` adds it, and its one-line help."""

    name: str
    module: str
    help: str


def add_commands(sub: argparse._SubParsersAction, commands: Sequence[Command], argv: Sequence[str], *, full: bool = False) -> None:
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


STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)  # every one takes the same path: a clean, run-wide stop


class StopRequested(KeyboardInterrupt):
    """A stop signal ended the run; ``signum`` is its number (exit status 128 + ``signum``)."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


class StopSignals:
    """SIGINT, SIGTERM and SIGHUP as a stop request: the first one raises ``StopRequested`` (a
    ``KeyboardInterrupt``: ends the run), later ones are only noted, and inside ``deferred()``
    (finishing a recording, stopping children) every signal is only noted, never an exception in
    the middle of writing a file.

    ``received`` is the first signal number (None if none came). ``restore()`` puts back the
    previous handlers. Main thread only (Python runs signal handlers there).
    """

    SIGNALS = STOP_SIGNALS

    def __init__(self) -> None:
        self.received: int | None = None
        self._deferred = 0
        self._previous = {sig: signal.signal(sig, self._handle) for sig in self.SIGNALS}

    def _handle(self, signum: int, _frame: object) -> None:
        first = self.received is None
        if first:
            self.received = signum
        if first and not self._deferred:
            raise StopRequested(signum)

    @contextlib.contextmanager
    def deferred(self) -> Iterator[None]:
        """Signals arriving in this block are noted, not raised (a stop request is then ``received``)."""
        self._deferred += 1
        try:
            yield
        finally:
            self._deferred -= 1

    def restore(self) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)


def on_stop_signals(callback: Callable[[], object]) -> None:
    """Call ``callback()`` (it must be safe in a signal handler) on SIGINT, SIGTERM and SIGHUP."""
    for sig in STOP_SIGNALS:
        signal.signal(sig, lambda *_: callback())


def guarded(prog: str, run: Callable[[], int | None]) -> int:
    """``run()``'s exit code; bad input or I/O errors print ``prog: error: ...`` and give 2, a stop signal N
    gives 128 + N (Ctrl-C 130), a closed stdout (a pipe into ``head``) gives 141 (128 + SIGPIPE) silently."""
    try:
        return int(run() or 0)
    except BrokenPipeError:  # stdout closed early (swarm info ... | head): quietly, as other Unix tools
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no second error when Python flushes stdout at exit
        return 141
    except (SwarmInputError, LocalizationError, OSError) as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 128 + (exc.signum if isinstance(exc, StopRequested) else signal.SIGINT)


def run_standalone(
    prog: str,
    add_arguments: Callable[[argparse.ArgumentParser], None],
    run: Callable[[argparse.Namespace], int | None],
    argv: list[str] | None = None,
) -> int:
    """Entry point of a command started as its own module (``python -m swarm_cli.agent``):
    the launcher starts processes this way so each imports only what it needs."""
    from swarm_cli.lifeline import hold_lifeline  # noqa: PLC0415

    hold_lifeline()  # started by a launcher: end with it, whatever killed it
    parser = argparse.ArgumentParser(prog=prog)
    add_arguments(parser)
    args = parser.parse_args(argv)
    return guarded(prog, lambda: run(args))


def leave(code: int) -> None:
    """Exit a process that held Zenoh sessions without interpreter finalization.

    A Zenoh thread still delivering a late sample (a closed session does not wait for it) would
    re-enter Python while the interpreter finalizes; CPython 3.11 then pthread_exit()s that Rust
    thread, whose unwinder aborts the process ("FATAL: exception not rethrown", signal 6). Call it
    once sessions and recordings are closed: only the standard streams need flushing.
    """
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)
