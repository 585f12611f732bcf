"""Which coordinator an agent obeys (``Agent._admit``), fed token events and messages in the orders a loaded machine
delivers them: liveliness events and commands travel on different subscriptions, so a takeover's first command can
overtake both the old token's end and the new token."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

from robot_agent.agent import _UNSEEN, Agent
from runtime.wire.keys import coord_alive_key
from runtime.wire.transport import loopback_hub

RUN = "epochs"
OLD, NEW, FOREIGN = 11, 12, 13


def agent() -> Agent:
    driver: Any = SimpleNamespace(simulated=False)  # a real robot: no truth answered to a new token
    return Agent(loopback_hub(7447)[1], RUN, 0, [0, 1], driver)  # settings only: no session is opened


def token(a: Agent, epoch: int, parent: int, alive: bool) -> None:
    a._on_coordinator(f"{coord_alive_key(RUN, epoch, parent)} {int(alive)}")


def test_a_takeovers_command_before_any_token_event_is_unseen_not_refused() -> None:
    a = agent()
    token(a, OLD, 0, True)
    assert a._admit(OLD) is None and a.bound == OLD
    assert a._admit(NEW) == _UNSEEN  # dropped: the new coordinator sends it again (a refusal would make it step down)
    token(a, NEW, OLD, True)  # the new token arrives before the old one's end
    assert a._admit(NEW) is None and a.bound == NEW
    token(a, OLD, 0, False)
    assert a._admit(OLD) is not None and a.bound == NEW  # the old coordinator is never obeyed again


def test_a_second_coordinator_of_a_live_run_is_refused_once_its_token_is_seen() -> None:
    a = agent()
    token(a, OLD, 0, True)
    assert a._admit(OLD) is None
    assert a._admit(FOREIGN) == _UNSEEN
    token(a, FOREIGN, 0, True)
    reason = a._admit(FOREIGN)
    assert reason is not None and reason != _UNSEEN and f"obeys the live coordinator epoch {OLD}" in reason
    assert a.bound == OLD


def test_a_gone_epoch_and_no_epoch_are_refused() -> None:
    a = agent()
    token(a, OLD, 0, True)
    token(a, OLD, 0, False)
    assert "which is gone" in str(a._admit(OLD))
    assert "carries no coordinator epoch" in str(a._admit(0))
