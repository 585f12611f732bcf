"""The library's worker pools start clean processes (``inchworm.runner.process_context``): a study or bench run in a
process that has a Zenoh session does not hang in a worker that inherited the session's objects."""

from __future__ import annotations

import gc
import threading

from inchworm.runner import ProcessExecutor, process_context
from runtime.wire.transport import open_loopback_hub, open_session


def _collect(k: int) -> int:
    """A task that drops every unreachable object the worker holds (a forked worker: the parent's)."""
    gc.collect()
    return k


def test_a_pool_started_after_a_zenoh_session_left_objects_for_the_collector_finishes():
    """A Zenoh session left open in a reference cycle (as a test or a script that did not close one leaves it) waits
    for the collector here; a forked worker drops its copy in its first collection, without the Zenoh runtime's
    threads, and blocks for good (a bench run hung so; with the ``fork`` start method this test's workers hang). The
    pool's two workers collect and answer within 60 s."""
    hub, member, _ = open_loopback_hub()
    with hub:
        gc.disable()  # the cycle waits for a collection, as garbage does between collections
        try:
            leaked = open_session(member)
            cycle: list[object] = [leaked, leaked.declare_subscriber("pools/cycle")]
            cycle.append(cycle)
            del cycle, leaked
            rows: list[tuple[int, int]] = []
            worker = threading.Thread(target=lambda: rows.extend(ProcessExecutor(2).imap(_collect, [1, 2])), daemon=True)
            worker.start()
            worker.join(60)
            assert not worker.is_alive(), "the pool's workers hung"
            assert sorted(rows) == [(0, 1), (1, 2)]
        finally:
            gc.enable()
            gc.collect()
    assert process_context().get_start_method() == "spawn"


def test_a_localizer_registered_with_a_lambda_is_named_before_a_pool_starts():
    """A spawned worker receives the parent's registered localizers by pickle: a lambda cannot go, and the pool says
    which localizer and what to do instead of failing in a worker."""
    import pytest

    from coordinator.localization.registry import register_localizer, unregister_localizer
    from inchworm.runner import pool_localizers
    from runtime.errors import SwarmInputError

    register_localizer("inline", lambda cfg: None)
    try:
        with pytest.raises(SwarmInputError, match="localizer 'inline' is registered with a factory worker processes cannot receive"):
            pool_localizers()
        with pytest.raises(SwarmInputError, match="'inline'"):
            list(ProcessExecutor(2).imap(_collect, [1, 2]))
    finally:
        unregister_localizer("inline")
    assert "inline" not in pool_localizers()
