"""The study runner: a list of seeded tasks, run by a pluggable executor, each result kept as it finishes.

A task is a picklable object with a ``key`` (unique in its study) that carries its own
seeds, so a row never depends on the worker or the order that computed it. An
``Executor`` maps a top-level function over the tasks and yields ``(index, row)`` as
rows finish, in any order; ``run_tasks`` returns the rows in task order. With a
``StudyLog`` every finished row is appended at once to ``<name>.jsonl`` (one JSON object
per line, flushed and synced) and the CSV beside it is rewritten; ``resume=True`` reads the
rows an interrupted study kept and runs only the missing tasks, so the final rows are the
same as those of an uninterrupted run (JSON keeps floats exactly).

Another executor is one small class with ``imap``: ``inchworm.dask_executor.DaskExecutor``
submits every task to a Dask cluster and yields rows from ``distributed.as_completed``;
``open_executor`` picks one from the study options (``--executor``, ``--workers``, ``--scheduler``).
"""

from __future__ import annotations

import contextlib
import json
import multiprocessing
import os
import signal
import threading
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any, Protocol, TypeVar

from runtime.errors import OptionError, OutputError, SwarmInputError
from runtime.paths import StrPath

T = TypeVar("T")
Row = dict[str, Any]


class Task(Protocol):
    """What the runner needs of a task: a key naming it within its study."""

    @property
    def key(self) -> str: ...


class Executor(Protocol):
    """Runs ``fn`` over ``items``, yielding ``(index, fn(items[index]))`` as each finishes (any order)."""

    def imap(self, fn: Callable[[T], Row], items: Sequence[T]) -> Iterator[tuple[int, Row]]: ...


class SerialExecutor:
    """Every task in this process, in order (tests, debugging, one core)."""

    def imap(self, fn: Callable[[T], Row], items: Sequence[T]) -> Iterator[tuple[int, Row]]:
        for i, item in enumerate(items):
            yield i, fn(item)


def process_context() -> multiprocessing.context.SpawnContext:
    """The start method of every worker pool of the library: ``spawn``. A forked worker inherits the parent's Zenoh
    objects without the threads of their runtime, and the first garbage collection that drops one blocks forever (a
    study or bench run after a Zenoh session in the same process hung so); a spawned worker starts clean."""
    return multiprocessing.get_context("spawn")


def register_localizers(localizers: dict[str, Any]) -> None:
    """A spawned worker process: the localizers registered in its parent (``pool_localizers``), registered here."""
    from coordinator.localization.registry import register_localizer  # noqa: PLC0415

    for name, factory in localizers.items():
        register_localizer(name, factory)


def pool_localizers() -> dict[str, Any]:
    """The localizers registered in this process (``register_localizer``), for a pool's workers (``register_localizers``);
    ``SwarmInputError`` naming one whose factory cannot be sent to another process (a lambda, a local class)."""
    import pickle  # noqa: PLC0415

    from coordinator.localization.registry import registered_localizers  # noqa: PLC0415

    localizers = registered_localizers()
    for name, factory in localizers.items():
        try:
            pickle.dumps(factory)
        except (pickle.PicklingError, AttributeError, TypeError) as exc:
            raise SwarmInputError(f"localizer {name!r} is registered with a factory worker processes cannot receive ({exc}): "
                                  "define it at the top level of a module, or use one worker") from None
    return localizers


def _worker_init(localizers: dict[str, Any]) -> None:
    """A worker process: the parent's registered localizers, one BLAS thread (the pool already uses every core), Ctrl-C
    handled by the parent only."""
    from threadpoolctl import threadpool_limits  # noqa: PLC0415

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    threadpool_limits(1)
    register_localizers(localizers)


def _call(job: tuple[Callable[[T], Row], int, T]) -> tuple[int, Row]:
    fn, i, item = job
    return i, fn(item)


class ProcessExecutor:
    """Tasks spread over ``workers`` local processes (``multiprocessing.Pool``); stopped at once on an error or Ctrl-C."""

    def __init__(self, workers: int | None = None) -> None:
        self.workers = max(1, workers or os.cpu_count() or 1)

    def imap(self, fn: Callable[[T], Row], items: Sequence[T]) -> Iterator[tuple[int, Row]]:
        if self.workers == 1 or len(items) <= 1:
            yield from SerialExecutor().imap(fn, items)
            return
        pool = process_context().Pool(min(self.workers, len(items)), initializer=_worker_init, initargs=(pool_localizers(),))
        try:
            yield from pool.imap_unordered(_call, [(fn, i, item) for i, item in enumerate(items)])
            pool.close()
        finally:
            pool.terminate()
            pool.join()


def default_executor(workers: int | None = None) -> Executor:
    """The local process pool (``workers``: default every core)."""
    return ProcessExecutor(workers)


EXECUTORS = ("local", "dask")


@contextlib.contextmanager
def open_executor(kind: str = "local", workers: int | None = None, scheduler: str | None = None) -> Iterator[Executor]:
    """The executor of a study: the local pool (``local``), a Dask ``LocalCluster`` of ``workers`` processes
    (``dask``), or the running Dask cluster at ``scheduler`` (``tcp://HOST:PORT``; then ``kind`` and ``workers``
    are not used); a cluster it starts is stopped on exit."""
    if scheduler is None and kind == "local":
        yield default_executor(workers)
        return
    if scheduler is None and kind != "dask":
        raise OptionError("executor", f"must be one of {', '.join(EXECUTORS)}, got {kind!r}")
    from inchworm.dask_executor import DaskExecutor, dask_client  # noqa: PLC0415

    with dask_client(scheduler, max(1, workers or os.cpu_count() or 1)) as client:
        yield DaskExecutor(client)


class StudyLog:
    """The rows of a study kept as they finish: ``folder/<name>.jsonl`` and ``folder/<name>.csv``.

    The first JSONL line holds the study's options; ``resume`` refuses a log made with other
    options (a one-line error naming the first difference). A line cut short by an
    interruption is ignored (its task runs again).
    """

    def __init__(self, folder: StrPath, name: str, options: dict[str, Any], resume: bool = False) -> None:
        folder = Path(folder)
        self.jsonl = folder / f"{name}.jsonl"
        self.csv = folder / f"{name}.csv"
        self.options = json.loads(json.dumps(options))  # as it reads back
        self.rows: dict[str, Row] = {}
        self._csv_rows: dict[str, Row] = {}
        if resume and self.jsonl.exists():
            self._read()
        else:
            try:
                folder.mkdir(parents=True, exist_ok=True)
                self.jsonl.write_text("")
            except OSError as exc:
                raise OutputError(f"cannot write the study log {self.jsonl}: {exc.strerror or exc}") from None
            self._write({"options": self.options})

    def _read(self) -> None:
        lines = self.jsonl.read_text().splitlines()
        try:
            head = json.loads(lines[0])["options"] if lines else None
        except (json.JSONDecodeError, KeyError, TypeError):
            head = None
        if head is None:
            raise OptionError("resume", f": {self.jsonl} is not a study log")
        if head != self.options:
            diff = next(k for k in sorted({*head, *self.options}) if head.get(k) != self.options.get(k))
            raise OptionError("resume", f": {self.jsonl} was made with {diff} = {head.get(diff)!r}, not {self.options.get(diff)!r}")
        for line in lines[1:]:
            try:
                entry = json.loads(line)
            except json.JSONDecodeError:
                continue  # the line being written when the study was stopped
            self.rows[entry["task"]] = entry["row"]
            if entry.get("csv", True):
                self._csv_rows[entry["task"]] = entry["row"]

    def _write(self, obj: dict[str, Any]) -> None:
        try:
            with open(self.jsonl, "a") as f:
                f.write(json.dumps(obj, separators=(",", ":")) + "\n")
                f.flush()
                os.fsync(f.fileno())
        except OSError as exc:
            raise OutputError(f"cannot write the study log {self.jsonl}: {exc.strerror or exc} (the runs before are kept: "
                              f"a resumed study goes on from them)") from None

    def add(self, key: str, row: Row, csv: bool = True) -> None:
        """Keep one finished row (``csv``: also in the CSV, rewritten now); a Ctrl-C meanwhile waits until both files agree."""
        with _interrupt_deferred():
            self.rows[key] = row
            self._write({"task": key, "row": row, **({} if csv else {"csv": False})})
            if csv:
                self._csv_rows[key] = row
                write_rows(self.csv, list(self._csv_rows.values()))

    def finish(self, rows: list[Row]) -> Path:
        """The final CSV: ``rows`` in the study's order."""
        return write_rows(self.csv, rows)


@contextlib.contextmanager
def _interrupt_deferred() -> Iterator[None]:
    """Ctrl-C (SIGINT) inside the block is raised as ``KeyboardInterrupt`` at its end (main thread only)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    received: list[int] = []
    previous = signal.signal(signal.SIGINT, lambda signum, _frame: received.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
    if received:
        raise KeyboardInterrupt


def run_tasks(
    fn: Callable[[T], Row],
    tasks: Sequence[T],
    *,
    executor: Executor | None = None,
    log: StudyLog | None = None,
    csv: bool = True,
    progress: Callable[[int, int], None] | None = None,
) -> list[Row]:
    """``fn(task)`` for every task, in task order; rows already in ``log`` are not run again."""
    keys = [t.key for t in tasks]  # type: ignore[attr-defined]
    if len(set(keys)) != len(keys):
        raise SwarmInputError("task keys must be unique within a study")
    rows: dict[int, Row] = {}
    if log is not None:
        rows = {i: log.rows[k] for i, k in enumerate(keys) if k in log.rows}
    todo = [i for i in range(len(tasks)) if i not in rows]
    if progress is not None and rows:
        progress(len(rows), len(tasks))
    for j, row in (executor or SerialExecutor()).imap(fn, [tasks[i] for i in todo]):
        i = todo[j]
        rows[i] = row
        if log is not None:
            log.add(keys[i], row, csv)
        if progress is not None:
            progress(len(rows), len(tasks))
    return [rows[i] for i in range(len(tasks))]


def write_rows(path: Path, rows: list[Row]) -> Path:
    """``rows`` as a CSV file with a header (the union of their keys, in order; missing cells empty)."""
    import csv  # noqa: PLC0415

    keys = list(dict.fromkeys(k for r in rows for k in r))
    tmp = path.with_name(path.name + ".tmp")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(tmp, "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=keys)
            writer.writeheader()
            writer.writerows({k: r.get(k, "") for k in keys} for r in rows)
        os.replace(tmp, path)
    except OSError as exc:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise OutputError(f"cannot write {path}: {exc.strerror or exc}") from None
    return path
