"""How every ``swarm`` command turns user errors into a message and an exit code (no tracebacks)."""

from __future__ import annotations

import argparse
import importlib
import os
import re
import signal
import sys
import threading
from collections.abc import Callable, Sequence
from typing import NamedTuple

from runtime.errors import OptionError, OutputError, RunConflictError, SwarmError, SwarmRunError

EXIT_INPUT = 2  # bad input, a connection that could not be made, a file that could not be read: nothing ran
EXIT_RUN = 3  # a run that started failed: robots lost, the run aborted or stopped
EXIT_CONFLICT = 4  # another coordinator holds the run
EXIT_OUTPUT = 5  # an output could not be written (coordinator.process.EXIT_OUTPUT)
EXIT_CODES: tuple[tuple[type[BaseException], int], ...] = (  # the first class that matches gives the exit code
    (OutputError, EXIT_OUTPUT),  # a recording that failed or stopped the run included
    (RunConflictError, EXIT_CONFLICT),
    (SwarmRunError, EXIT_RUN),  # before SwarmConnectionError: a hub lost during a run is a run that failed
    (SwarmError, EXIT_INPUT),  # SwarmInputError, LocalizationError, SwarmConnectionError
    (OSError, EXIT_INPUT),
)


def exit_code(exc: BaseException) -> int | None:
    """The exit status of a command that ended with ``exc`` (``EXIT_CODES``; runtime.errors has the hierarchy), None for
    an exception that is not a user's error (a bug: its traceback is shown)."""
    return next((code for kind, code in EXIT_CODES if isinstance(exc, kind)), None)


def cli_message(exc: BaseException) -> str:
    """The error's one line as a command says it: an option out of range is named by its flag (``OptionError``)."""
    return exc.flag_message() if isinstance(exc, OptionError) else str(exc)


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


def on_stop_signals(callback: Callable[[], object]) -> None:
    """Call ``callback()`` on SIGINT, SIGTERM and SIGHUP, on a thread of its own: never inside the interrupted main
    thread, which may hold the very lock the callback takes (an ``Event.set()`` while the main thread is in that
    Event's ``wait()`` deadlocks). The handler only writes a byte to a pipe."""
    read_end, write_end = os.pipe()

    def watch() -> None:
        while os.read(read_end, 1):
            callback()

    threading.Thread(target=watch, name="stop-signals", daemon=True).start()
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, lambda *_: os.write(write_end, b"s"))


def guarded(prog: str, run: Callable[[], int | None]) -> int:
    """``run()``'s exit code; a ``SwarmError`` or an I/O error prints ``prog: error: ...`` (an option named by its flag)
    and gives its ``exit_code``, a stop signal N
    gives 128 + N (Ctrl-C 130), a closed stdout (a pipe into ``head``) gives 141 (128 + SIGPIPE) silently."""
    try:
        return int(run() or 0)
    except BrokenPipeError:  # stdout closed early (swarm info ... | head): quietly, as other Unix tools
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no second error when Python flushes stdout at exit
        return 141
    except (SwarmError, OSError) as exc:
        print(f"{prog}: error: {cli_message(exc)}", file=sys.stderr)
        return exit_code(exc) or EXIT_INPUT
    except KeyboardInterrupt as exc:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 128 + getattr(exc, "signum", signal.SIGINT)  # coordinator.stop.StopRequested carries the signal


def limit_blas_threads() -> None:
    """One BLAS thread in this process and the processes it starts (an entry point, before numpy loads).

    The commands parallelise over processes (one per core), so each keeps its BLAS to one
    thread: several BLAS threads per process only oversubscribe the cores and make the small
    batched solves of the Monte Carlo planner erratic. A BLAS already loaded (``main`` called
    from Python) is limited through threadpoolctl.
    """
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")
    if "numpy" in sys.modules:
        from threadpoolctl import threadpool_limits  # noqa: PLC0415

        threadpool_limits(1)


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
    parser = argparse.ArgumentParser(prog=prog)
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
