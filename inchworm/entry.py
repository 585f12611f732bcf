"""What every process of ours does at its entry: user errors as one line and an exit code, stop signals, BLAS threads, exit.

Every exit status of a user's error comes from one table, ``EXIT_CODES`` (the class of the error, ``runtime.errors``).

``swarm_cli.entry`` (the commands) and ``inchworm.spawn`` (processes started from specs) share these.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
from collections.abc import Callable

from runtime.errors import OptionError, OutputError, RunConflictError, SwarmError, SwarmRunError

EXIT_INPUT = 2  # bad input, a connection that could not be made, a file that could not be read: nothing ran
EXIT_RUN = 3  # a run that started failed: robots lost, the run aborted or stopped
EXIT_CONFLICT = 4  # another coordinator holds the run
EXIT_OUTPUT = 5  # an output could not be written (coordinator.node.process.EXIT_OUTPUT)
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
    """The error's one line as a command says it: an option out of range is named by its flag (``OptionError``), an
    I/O error of the system by its file and reason (``out/x: Not a directory``, not ``[Errno 20] ...``)."""
    if isinstance(exc, OptionError):
        return exc.flag_message()
    if isinstance(exc, OSError) and not isinstance(exc, SwarmError) and exc.strerror:
        return f"{exc.filename}: {exc.strerror}" if exc.filename is not None else exc.strerror
    return str(exc)


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
        return 128 + getattr(exc, "signum", signal.SIGINT)  # coordinator.node.stop.StopRequested carries the signal


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
