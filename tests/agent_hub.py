"""Robot 0's simulated agent on a real loopback Zenoh hub, with the test acting as its coordinator."""

from __future__ import annotations

import contextlib
import queue
import threading
import time
from collections.abc import Iterator

import numpy as np

from robot_agent.agent import Agent
from robot_agent.driver import SimDriver
from runtime.models.config import ModelConfig
from runtime.wire.keys import alive_wildcard, coord_alive_key
from runtime.wire.transport import alive_now, declare_token, open_loopback_hub, subscribe_queue


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
        token = declare_token(hub, coord_alive_key(run, epoch))
        time.sleep(0.3)  # the agent learns of its coordinator
        try:
            yield hub, agent, seen
        finally:
            token.undeclare()
            agent.stop()
            thread.join(timeout=5)
