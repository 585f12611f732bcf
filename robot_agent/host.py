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

With ``links`` (``swarm agent --link``, the gateway PC's layout: one process per radio port) the host also
runs the link of its robots' port on its session, on a thread of its own. Its agents hand their requests
to the link directly and get its replies back without a Zenoh hop (``GatewayDriver.use_link``); the
requests and replies are still published on the robots' keys, so a recorder gets the same messages. The
links start before the agents, which wait for their tokens, and stop after the last agent ended; a link
that stops by itself (its device failed) drops its token, so its robots' agents report them lost.
"""

from __future__ import annotations

import logging
import queue
import threading
from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING

from robot_agent.agent import Agent
from robot_agent.gateway_driver import GatewayDriver
from runtime.errors import SwarmInputError
from runtime.wire.transport import ZenohSettings, claim_identities, open_session

if TYPE_CHECKING:
    import zenoh

    from robot_agent.link import Link

LinkFactory = Callable[[object], "Link"]  # session -> the link of one port, its device opened (``Link.open``)
LINK_JOIN_S = 2.0  # s a link gets to publish its final stats once asked to stop

_log = logging.getLogger(__name__)


class AgentHost:
    """Serves ``agents`` (distinct robots of one run) on one session opened from ``settings``, and the ``links``
    (port name -> its factory) of their ports. Refuses (``SwarmInputError``) to start when one of these robots or
    ports already has a live agent or link on the run."""

    def __init__(self, settings: ZenohSettings, agents: Sequence[Agent], links: Mapping[str, LinkFactory] | None = None) -> None:
        robots = [a.robot for a in agents]
        if not robots or len(set(robots)) != len(robots):
            raise SwarmInputError(f"an agent host needs distinct robots, got {robots}")
        self.settings = settings
        self.agents = list(agents)
        self.links = dict(links or {})
        self.link_summaries: list[str] = []  # one line per link that ran (``Link.summary``), once ``run`` returned
        self.results: dict[int, int] = {}  # robot -> its agent's run() status, once it returned

    def stop(self) -> None:
        """Ask every agent to end (safe from a signal handler or another thread)."""
        for agent in self.agents:
            agent.stop()

    def run(self) -> int:
        """Serve until ``stop()`` and every agent has ended; 3 if a robot was lost, else 0. Closes the session."""
        with open_session(self.settings) as session:
            claim_identities(session, self.agents[0].run_id, [a.robot for a in self.agents], self.links)
            links = self._start_links(session)
            try:
                if all(agent.driver.instantaneous for agent in self.agents):
                    self.serve_together(session)
                else:
                    threads = [threading.Thread(target=self._serve, args=(agent, session), name=f"agent-{agent.robot}", daemon=True)
                               for agent in self.agents]
                    for thread in threads:
                        thread.start()
                    for thread in threads:
                        thread.join()
            finally:
                self._stop_links(links)
        lost = sorted(r for r, status in self.results.items() if status == 3)
        if lost:
            _log.error("robots %s were lost", lost)
        return 3 if lost else 0

    def serve_together(self, session: zenoh.Session) -> None:
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

    def _start_links(self, session: zenoh.Session) -> list[tuple[Link, threading.Thread]]:
        """Open each link's device and run it on a thread; a device that cannot be opened stops the ones started and raises."""
        started: list[tuple[Link, threading.Thread]] = []
        try:
            for factory in self.links.values():
                link = factory(session)
                for agent in self.agents:  # its robots' requests and replies stay in this process (``GatewayDriver.use_link``)
                    if isinstance(agent.driver, GatewayDriver) and agent.driver.port == link.port.name:
                        agent.driver.use_link(link)
                thread = threading.Thread(target=link.run, name=f"link-{link.port.name}", daemon=True)
                started.append((link, thread))
                thread.start()
        except BaseException:
            self._stop_links(started)
            raise
        return started

    def _stop_links(self, links: list[tuple[Link, threading.Thread]]) -> None:
        for link, _thread in links:
            link.stop()
        for link, thread in links:
            thread.join(timeout=LINK_JOIN_S)
            link.close()
            self.link_summaries.append(link.summary())

    def _serve(self, agent: Agent, session: zenoh.Session) -> None:
        try:
            self.results[agent.robot] = agent.run(session)
        except Exception:  # noqa: BLE001 - one agent's failure to start must not take its neighbours down
            _log.exception("robot %d: its agent failed", agent.robot)
            self.results[agent.robot] = 1


class _Feed:
    """One agent's inbox in a host serving its agents together: puts ``(agent, item)`` on the shared queue."""

    def __init__(self, shared: queue.SimpleQueue[tuple[Agent, tuple[str, bytes]]], agent: Agent) -> None:
        self._shared, self._agent = shared, agent

    def put(self, item: tuple[str, bytes]) -> None:
        self._shared.put((self._agent, item))
