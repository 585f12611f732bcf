"""The coordinator's questions to the hub about the run's tokens, on a real loopback hub: answered completely on a
session that also watches those tokens (as every coordinator's does), where a bare liveliness query sometimes
answers empty (Zenoh 1.x; coordinator/node/zenoh_backend.py, ``VIEW_TRIES``)."""

from __future__ import annotations

import zenoh

from coordinator.node.zenoh_backend import LiveRun, live_coordinators, live_run
from runtime.wire.keys import alive_key, alive_wildcard, coord_alive_key, run_wildcard
from runtime.wire.transport import alive_now, declare_token, open_loopback_hub, open_session, watch_liveliness
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



def test_a_session_without_a_token_of_its_own_asks_past_empty_and_incomplete_answers(monkeypatch):
    """The check before a coordinator starts, a replay's and a status ask on a session that declared no token of the
    run, where an answer cannot be checked for its own token. The first answers of the real session's queries are
    emptied (as a session that watches the tokens answers now and then) or lose a token: every question still names
    the live coordinator and every agent, after up to ``VIEW_TRIES - 1`` empty answers (``VIEW_TRIES - VIEW_ANSWERS`` before
    an incomplete one); a run with nothing alive (every
    answer empty) answers empty. Then 200 questions, unaltered, on a session that watches the run's tokens."""
    from coordinator.node import zenoh_backend

    hub, member, _ = open_loopback_hub()
    with hub, open_session(member) as agents, open_session(member) as coordinator, open_session(member) as checker:
        robots = [declare_token(agents, alive_key(RUN, r)) for r in range(4)]
        live = declare_token(coordinator, coord_alive_key(RUN, 7, 3))
        wait_for(lambda: len(alive_now(checker, run_wildcard(RUN))) == 5, 10, "the run's tokens at the hub")
        answers: list[set[str]] = []

        def altered(empty: int, lose: str | None = None) -> None:
            """The session's next ``empty`` answers empty, the one after without the key ending in ``lose``."""
            answers.clear()

            def ask(session: zenoh.Session, key_expr: str, timeout_s: float = 1.0) -> set[str]:
                keys = alive_now(session, key_expr, timeout_s)
                answers.append(keys)
                if len(answers) <= empty:
                    return set()
                return {k for k in keys if lose is None or len(answers) > empty + 1 or not k.endswith(lose)}

            monkeypatch.setattr(zenoh_backend, "alive_now", ask)

        for empty in range(zenoh_backend.VIEW_TRIES):
            altered(empty)
            assert live_coordinators(checker, RUN) == {7: 3}, f"{empty} empty answers"
            if empty > zenoh_backend.VIEW_TRIES - zenoh_backend.VIEW_ANSWERS:
                continue  # an incomplete answer needs another to unite with
            altered(empty, lose="/7/3")
            assert live_run(checker, RUN) == LiveRun(frozenset(range(4)), {7: 3}, True), f"{empty} empty answers, one without the coordinator"
            altered(empty, lose="robot/2")
            assert live_run(checker, RUN).robots == frozenset(range(4)), f"{empty} empty answers, one without robot 2"
        altered(zenoh_backend.VIEW_TRIES)
        assert live_coordinators(checker, RUN) == {} and len(answers) == zenoh_backend.VIEW_TRIES  # asked as often as it may
        assert live_run(checker, "other") == LiveRun(frozenset(), {}, False)
        monkeypatch.undo()

        seen: set[str] = set()
        watchers = [watch_liveliness(checker, alive_wildcard(RUN), lambda key, alive: seen.add(key)),
                    watch_liveliness(checker, coord_alive_key(RUN), lambda key, alive: seen.add(key))]
        wait_for(lambda: len(seen) == 5, 10, "the checker's view of the run's tokens")
        views = [live_run(checker, RUN) for _ in range(200)]
        assert all(v == LiveRun(frozenset(range(4)), {7: 3}, True) for v in views), [v for v in views if not v.complete][:3]
        for token in (*robots, live, *watchers):
            token.undeclare()
