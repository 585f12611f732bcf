"""The coordinator's questions to the hub about the run's tokens, on a real loopback hub: answered completely on a
session that also watches those tokens (as every coordinator's does), where a bare liveliness query sometimes
answers empty (Zenoh 1.x; coordinator/node/zenoh_backend.py, ``VIEW_TRIES``)."""

from __future__ import annotations

from coordinator.node.zenoh_backend import live_coordinators
from runtime.wire.keys import alive_key, alive_wildcard, coord_alive_key
from runtime.wire.transport import declare_token, open_loopback_hub, open_session, watch_liveliness
from tests.waiting import wait_for

RUN = "tokens"


def test_the_live_coordinators_are_all_named_on_a_session_that_watches_them():
    """Epoch 5 watches the robots' and coordinators' tokens and holds its own; epoch 9 took the run over from it. Every
    one of 300 answers names both (a bare query of the same session answers empty a few times in a hundred)."""
    hub, member, _ = open_loopback_hub()
    with hub, open_session(member) as agents, open_session(member) as standby, open_session(member) as coordinator:
        robots = [declare_token(agents, alive_key(RUN, r)) for r in range(6)]
        seen: set[str] = set()
        watchers = [watch_liveliness(coordinator, alive_wildcard(RUN), lambda key, alive: seen.add(key)),
                    watch_liveliness(coordinator, coord_alive_key(RUN), lambda key, alive: seen.add(key))]
        own = declare_token(coordinator, coord_alive_key(RUN, 5))
        taker = declare_token(standby, coord_alive_key(RUN, 9, 5))
        wait_for(lambda: len(seen) == 8, 10, "the coordinator's view of the run's tokens")
        answers = [live_coordinators(coordinator, RUN, own=5) for _ in range(300)]
        assert all(a == {5: 0, 9: 5} for a in answers), [a for a in answers if a != {5: 0, 9: 5}][:3]
        for token in (*robots, own, taker, *watchers):
            token.undeclare()
