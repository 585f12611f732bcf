"""Many robot agents in one process: one Zenoh session, one thread per ``Agent``.

A process costs ~75 MB (Python, numpy, Zenoh), an ``Agent`` on a shared session well
under 1 MB, so a few processes of many agents each carry hundreds of robots. On the wire
nothing changes: every agent declares its own liveliness token, subscribes to its own
keys, drives its own driver and draws from its own random streams (``runtime.models.rng``), so a
coordinator cannot tell a hosted agent from an agent process, and a run gives the same
numbers however the robots are spread over processes. Each agent's loop runs on its own
thread (Zenoh callbacks only enqueue, as in ``robot_agent.agent``); a robot lost ends its
own loop and drops its own token, the others keep serving.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Sequence

from robot_agent.agent import Agent
from runtime.wire.transport import ZenohSettings, open_session

_log = logging.getLogger(__name__)


class AgentHost:
    """Serves ``agents`` (distinct robots of one run) on one session opened from ``settings``."""

    def __init__(self, settings: ZenohSettings, agents: Sequence[Agent]) -> None:
        robots = [a.robot for a in agents]
        if not robots or len(set(robots)) != len(robots):
            raise ValueError(f"an agent host needs distinct robots, got {robots}")
        self.settings = settings
        self.agents = list(agents)
        self.results: dict[int, int] = {}  # robot -> its agent's run() status, once it returned

    def stop(self) -> None:
        """Ask every agent to end (safe from a signal handler or another thread)."""
        for agent in self.agents:
            agent.stop()

    def run(self) -> int:
        """Serve until ``stop()`` and every agent has ended; 3 if a robot was lost, else 0. Closes the session."""
        with open_session(self.settings) as session:
            threads = [threading.Thread(target=self._serve, args=(agent, session), name=f"agent-{agent.robot}", daemon=True)
                       for agent in self.agents]
            for thread in threads:
                thread.start()
            for thread in threads:
                thread.join()
        lost = sorted(r for r, status in self.results.items() if status == 3)
        if lost:
            _log.error("robots %s were lost", lost)
        return 3 if lost else 0

    def _serve(self, agent: Agent, session) -> None:
        try:
            self.results[agent.robot] = agent.run(session)
        except Exception:  # noqa: BLE001 - one agent's failure to start must not take its neighbours down
            _log.exception("robot %d: its agent failed", agent.robot)
            self.results[agent.robot] = 1
