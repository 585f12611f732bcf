"""Robot 0's simulated agent on a real loopback Zenoh hub, with the test acting as its coordinator; a coordinator's token
declared once simulated agents have it (``declare_coordinator``)."""

from __future__ import annotations

import contextlib
import queue
import threading
import time
from collections.abc import Iterator

import numpy as np
import zenoh

from robot_agent.agent import Agent
from robot_agent.driver import SimDriver
from runtime.models.config import ModelConfig
from runtime.wire.keys import alive_wildcard, coord_alive_key, truth_wildcard
from runtime.wire.messages import TruthMessage, decode
from runtime.wire.transport import alive_now, declare_token, open_loopback_hub, subscribe, subscribe_queue
from tests.waiting import wait_for


def declare_coordinator(session: zenoh.Session, run: str, epoch: int, robots: list[int], timeout_s: float = 10.0) -> zenoh.LivelinessToken:
    """The liveliness token of coordinator ``epoch`` of ``run`` on ``session``, once the simulated agents of ``robots``
    have it: each answers a new coordinator with its truth of step 0, stamped after the token was declared. (A message
    of an epoch whose token has not reached an agent is dropped, for its coordinator to send again; a test sends once.)
    The subscriptions ``session`` declared before have reached the agents by then too: one link, in order."""
    truths: dict[int, int] = {}

    def on_truth(key: str, payload: bytes) -> None:
        truth = decode(payload, TruthMessage)
        if truth.step == 0:
            truths[truth.robot] = max(truths.get(truth.robot, 0), truth.stamp_ns)

    sub = subscribe(session, truth_wildcard(run), on_truth)
    try:
        declared_ns = time.time_ns()
        token = declare_token(session, coord_alive_key(run, epoch))
        wait_for(lambda: all(truths.get(r, 0) > declared_ns for r in robots), timeout_s,
                 f"the agents of robots {robots} answering coordinator epoch {epoch}")
    finally:
        sub.undeclare()
    return token


@contextlib.contextmanager
def agent_on_hub(run: str, epoch: int, pose: np.ndarray, watch_key: str, motion_time_s: float = 0.0) -> Iterator[tuple[object, Agent, queue.Queue]]:
    """(hub session, robot 0's agent of robots [0, 1] at ``pose`` (motions taking ``motion_time_s``), queue of what is
    published on ``watch_key``).

    The agent is up (its liveliness token seen) and has learnt of the coordinator token of ``epoch``
    before the block runs; on leaving, the token is withdrawn and the agent stopped.
    """
    hub, member, _ = open_loopback_hub()
    with hub:
        agent = Agent(member, run, 0, [0, 1], SimDriver(0, [0, 1], np.asarray(pose, dtype=float), ModelConfig(), seed=1,
                                                                motion_time_s=motion_time_s))
        thread = threading.Thread(target=agent.run, daemon=True)
        thread.start()
        _, seen = subscribe_queue(hub, watch_key)
        deadline = time.monotonic() + 10
        while not alive_now(hub, alive_wildcard(run)):
            assert time.monotonic() < deadline, "the agent did not come up"
            time.sleep(0.02)
        token = declare_coordinator(hub, run, epoch, [0])
        try:
            yield hub, agent, seen
        finally:
            token.undeclare()
            agent.stop()
            thread.join(timeout=5)
