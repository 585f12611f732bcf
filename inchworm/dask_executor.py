"""Studies on a Dask cluster: every seeded task a Dask future, each row kept as its future completes.

``DaskExecutor(client)`` is an ``inchworm.runner.Executor``: it submits every task and yields
rows from ``distributed.as_completed``, so progress, the JSONL log and ``--resume`` behave as
with the local pool. Seeds belong to tasks, so rows are bit-identical whatever the cluster,
its number of workers or the order they finish in. A worker lost mid-study is survived: the
scheduler runs its tasks again on another worker (up to ``distributed.scheduler.allowed-failures``
times). Each task runs with one BLAS thread, like the local pool's workers. Needs the ``dask``
extra (``pip install 'inchworm-swarm[dask]'``); docs/scale-out.md shows multi-host use.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator, Sequence
from typing import TYPE_CHECKING, Any, TypeVar

from runtime.errors import OptionError, SwarmInputError

if TYPE_CHECKING:
    from distributed import Client

T = TypeVar("T")
CONNECT_TIMEOUT_S = 10.0  # how long to try reaching a scheduler before giving up (s)


def _one_blas_thread(fn: Callable[[T], dict[str, Any]], item: T) -> dict[str, Any]:
    """``fn(item)`` with one BLAS thread (a worker runs one task per thread; more would oversubscribe its cores)."""
    from threadpoolctl import threadpool_limits  # noqa: PLC0415

    with threadpool_limits(1):
        return fn(item)


class DaskExecutor:
    """Tasks as futures on ``client``'s cluster, yielded ``(index, row)`` as they complete; the rest cancelled on an error."""

    def __init__(self, client: Client) -> None:
        self.client = client

    def imap(self, fn: Callable[[T], dict[str, Any]], items: Sequence[T]) -> Iterator[tuple[int, dict[str, Any]]]:
        from distributed import as_completed  # noqa: PLC0415

        futures = {self.client.submit(_one_blas_thread, fn, item, pure=False): i for i, item in enumerate(items)}
        try:
            for future in as_completed(futures):
                yield futures[future], future.result()
        finally:
            self.client.cancel(list(futures))


@contextlib.contextmanager
def dask_client(scheduler: str | None = None, workers: int = 1) -> Iterator[Client]:
    """A client of the scheduler at ``scheduler`` (``tcp://HOST:PORT``), or of a ``LocalCluster`` of ``workers``
    single-threaded processes on this host (``scheduler=None``); closed on exit."""
    try:
        from distributed import Client, LocalCluster  # noqa: PLC0415
    except ImportError:
        raise SwarmInputError("the Dask executor needs the dask extra: pip install 'inchworm-swarm[dask]'") from None
    if scheduler is None:
        with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, \
                Client(cluster) as client:
            yield client
        return
    try:
        client = Client(scheduler, timeout=CONNECT_TIMEOUT_S)
    except (OSError, ValueError, TypeError) as exc:
        reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise OptionError("scheduler", f"{scheduler}: cannot reach a Dask scheduler ({reason})") from None
    with client:
        yield client
