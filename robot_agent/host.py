"""Many robot agents in one process: one Zenoh session; one thread for them all, or one per ``Agent``.

A process costs ~75 MB (Python, numpy, Zenoh), an ``Agent`` on a shared session well
under 1 MB, so a few processes of many agents each carry hundreds of robots. On the wire
nothing changes: every agent declares its own liveliness token, subscribes to its own
keys, drives its own driver and draws from its own random streams (``runtime.models.rng``), so a
coordinator cannot tell a hosted agent from an agent process, and a run gives the same
numbers however the robots are spread over processes. Zenoh callbacks only enqueue, as in
``robot_agent.agent``; a robot lost ends its own agent and drops its own token, the others keep serving.

Agents whose drivers are all ``instantaneous`` (simulated robots without motion time) never block, so one
thread serves them all from one queue (``serve_together``): a message wakes one thread instead of its
agent's, and a host of 50 agents no longer switches among 100 threads each step. Agents with drivers
whose motions take time (the gateway, a lab's driver) each get a thread of their own, so one robot's
motion never delays another's command.
"""

from __future__ import annotations

import logging
import queue
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
            if all(agent.driver.instantaneous for agent in self.agents):
                self.serve_together(session)
            else:
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

    def serve_together(self, session) -> None:
        """Every agent on this thread, from one queue, until each has ended (``stop()`` or its robot lost)."""
        shared: queue.SimpleQueue[tuple[Agent, tuple[str, bytes]]] = queue.SimpleQueue()
        active: set[Agent] = set()
        for agent in self.agents:
            try:
                agent.open(session, _Feed(shared, agent))
            except Exception:  # noqa: BLE001 - one agent's failure to start must not take its neighbours down
                _log.exception("robot %d: its agent failed", agent.robot)
                self.results[agent.robot] = 1
                continue
            active.add(agent)

        def end(agent: Agent) -> None:
            agent.close()
            active.discard(agent)
            self.results[agent.robot] = agent.outcome()

        for agent in [a for a in active if a.stopped]:  # stopped while the others opened: its stop went to its own queue
            end(agent)
        while active:
            agent, (key, payload) = shared.get()
            if agent in active and not agent.serve(key, payload):
                end(agent)

    def _serve(self, agent: Agent, session) -> None:
        try:
            self.results[agent.robot] = agent.run(session)
        except Exception:  # noqa: BLE001 - one agent's failure to start must not take its neighbours down
            _log.exception("robot %d: its agent failed", agent.robot)
            self.results[agent.robot] = 1


class _Feed:
    """One agent's inbox in a host serving its agents together: puts ``(agent, item)`` on the shared queue."""

    def __init__(self, shared: queue.SimpleQueue, agent: Agent) -> None:
        self._shared, self._agent = shared, agent

    def put(self, item: tuple[str, bytes]) -> None:
        self._shared.put((self._agent, item))
