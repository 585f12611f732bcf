"""The Zenoh key space of a run (the contract is ``docs/protocol.md``).

Every key starts with ``swarm/<run>``::

    swarm/<run>/robot/<id>/cmd       MotionCommand      coordinator -> agent
    swarm/<run>/robot/<id>/observe   ObserveRequest     coordinator -> agent
    swarm/<run>/robot/<id>/status    Status             agent -> coordinator
    swarm/<run>/robot/<id>/obs       ObservationReport  agent -> coordinator
    swarm/<run>/robot/<id>/linkreq   LinkRequest        gateway agent -> link process
    swarm/<run>/robot/<id>/linkrep   LinkReply          link process -> gateway agent
    swarm/<run>/link/<port>/stats    LinkStats          link process -> recorder, tools
    swarm/<run>/estop                EmergencyStop      operator, launcher -> agents, links
    swarm/<run>/estop/ack            EstopAck           agents, links -> whoever stopped the run
    swarm/<run>/coord/plan           PlanMessage        coordinator -> all
    swarm/<run>/coord/estimate       EstimateMessage    coordinator -> all
    swarm/<run>/coord/event          RobotEvent         coordinator -> all (robot lost / rejoined)
    swarm/<run>/sim/truth/<id>       TruthMessage       simulated agent -> coordinator, recorder
    swarm/<run>/sim/truths           TruthSetMessage    coordinator -> simulated agents
    swarm/<run>/sim/contact          ContactMessage     coordinator -> recorder, tools (bodies touched)
    swarm/<run>/sim/physics          PhysicsEvent       the physical world's host -> recorder, tools (true poses, contacts, stalls)
    swarm/<run>/alive/robot/<id>     liveliness token of an agent
    swarm/<run>/coord/checkpoint     Checkpoint         coordinator -> standby coordinators, recorder
    swarm/<run>/alive/coord/<epoch>/<parent>  liveliness token of the coordinator (its epoch; the epoch it took over from, 0 = none)
    swarm/<run>/alive/link/<port>    liveliness token of the link process of a port

Run ids and port names are 1-64 characters of ``[A-Za-z0-9_.-]`` starting with a letter or digit,
so they never hold a key separator or a Zenoh wildcard. Robot ids are integers in
[0, 2^63 - 1] written in decimal without leading zeros, so each robot has one key.
"""

from __future__ import annotations

import functools
import re
from typing import NamedTuple

import numpy as np

from runtime.errors import SwarmInputError

ROOT = "swarm"
RUN_PATTERN = r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}"
MAX_ROBOT_ID = 2**63 - 1
ROBOT_LEAVES = ("cmd", "observe", "status", "obs", "linkreq", "linkrep")
COORD_LEAVES = ("plan", "estimate", "event", "checkpoint")

_RUN = re.compile(RUN_PATTERN)
_ID = re.compile(r"0|[1-9][0-9]{0,18}")


class KeyspaceError(SwarmInputError):
    """A key, run id or robot id that is not part of the swarm key space."""


class ParsedKey(NamedTuple):
    """A swarm key split up: ``kind`` is robot, coord, sim, link, estop or alive; ``robot`` is None where no robot is named."""

    run: str
    kind: str
    robot: int | None
    leaf: str


def _name(value: str, what: str) -> str:
    """``value`` if it is a valid name chunk (run id, port name), else ``KeyspaceError`` saying why."""
    if not isinstance(value, str) or not _RUN.fullmatch(value):
        raise KeyspaceError(
            f"{what} {value!r} is invalid: use 1-64 characters of A-Z a-z 0-9 _ . - starting with a letter or digit"
        )
    return value


def validate_run(run: str) -> str:
    """``run`` if it is a valid run id, else ``KeyspaceError`` saying why."""
    return _name(run, "run id")


def validate_robot_id(robot_id: int) -> int:
    """``robot_id`` as an int if it is an integer in [0, 2^63 - 1]."""
    if isinstance(robot_id, (bool, np.bool_)) or not isinstance(robot_id, (int, np.integer)):
        raise KeyspaceError(f"robot id {robot_id!r} is not an integer")
    if not 0 <= robot_id <= MAX_ROBOT_ID:
        raise KeyspaceError(f"robot id {robot_id} is outside [0, 2^63 - 1]")
    return int(robot_id)


def robot_key(run: str, robot_id: int, leaf: str) -> str:
    """``swarm/<run>/robot/<id>/<leaf>``, leaf one of ``ROBOT_LEAVES``."""
    if leaf not in ROBOT_LEAVES:
        raise KeyspaceError(f"robot key leaf {leaf!r} is not one of {ROBOT_LEAVES}")
    return f"{ROOT}/{validate_run(run)}/robot/{validate_robot_id(robot_id)}/{leaf}"


def coord_key(run: str, leaf: str) -> str:
    """``swarm/<run>/coord/<leaf>``, leaf one of ``COORD_LEAVES``."""
    if leaf not in COORD_LEAVES:
        raise KeyspaceError(f"coordinator key leaf {leaf!r} is not one of {COORD_LEAVES}")
    return f"{ROOT}/{validate_run(run)}/coord/{leaf}"


def truth_key(run: str, robot_id: int) -> str:
    """``swarm/<run>/sim/truth/<id>``: a simulated robot's true pose (simulation only)."""
    return f"{ROOT}/{validate_run(run)}/sim/truth/{validate_robot_id(robot_id)}"


def validate_port(port: str) -> str:
    """``port`` if it is a valid link port name (same rule as run ids), else ``KeyspaceError``."""
    return _name(port, "port name")


def link_stats_key(run: str, port: str) -> str:
    """``swarm/<run>/link/<port>/stats``: the statistics of the link process of one serial/radio port."""
    return f"{ROOT}/{validate_run(run)}/link/{validate_port(port)}/stats"


def estop_key(run: str) -> str:
    """``swarm/<run>/estop``: emergency stop of every robot of the run."""
    return f"{ROOT}/{validate_run(run)}/estop"


def estop_ack_key(run: str) -> str:
    """``swarm/<run>/estop/ack``: each agent and link acknowledges every emergency stop it acted on."""
    return f"{ROOT}/{validate_run(run)}/estop/ack"


def alive_key(run: str, robot_id: int) -> str:
    """``swarm/<run>/alive/robot/<id>``: the liveliness token an agent declares while it runs."""
    return f"{ROOT}/{validate_run(run)}/alive/robot/{validate_robot_id(robot_id)}"


def link_alive_key(run: str, port: str) -> str:
    """``swarm/<run>/alive/link/<port>``: the liveliness token the link process of ``port`` declares while it runs."""
    return f"{ROOT}/{validate_run(run)}/alive/link/{validate_port(port)}"


def coord_alive_key(run: str, epoch: int | None = None, parent: int = 0) -> str:
    """The coordinator's liveliness token: with ``epoch``, ``swarm/<run>/alive/coord/<epoch>/<parent>``, the token
    the coordinator of that epoch declares while it runs (``parent``: the epoch whose run it took over, 0 = a new
    run); without, ``swarm/<run>/alive/coord/**``, the expression matching every coordinator's token of the run
    (what a watcher passes to ``watch_liveliness`` or ``alive_now``; ``parse_coord_token`` reads a key)."""
    if epoch is None:
        return f"{ROOT}/{validate_run(run)}/alive/coord/**"
    if not 1 <= validate_robot_id(epoch) or validate_robot_id(parent) == epoch:
        raise KeyspaceError(f"coordinator epoch {epoch} must be >= 1 and differ from its parent {parent}")
    return f"{ROOT}/{validate_run(run)}/alive/coord/{epoch}/{parent}"


def parse_coord_token(key: str) -> tuple[int, int] | None:
    """``(epoch, parent)`` of a coordinator token key (``coord_alive_key(run, epoch, parent)``), None for any other key."""
    parts = key.split("/") if isinstance(key, str) else []
    if len(parts) != 6 or parts[0] != ROOT or parts[2:4] != ["alive", "coord"] or not _RUN.fullmatch(parts[1]):
        return None
    if not (_ID.fullmatch(parts[4]) and _ID.fullmatch(parts[5])):
        return None
    epoch, parent = int(parts[4]), int(parts[5])
    return (epoch, parent) if 1 <= epoch <= MAX_ROBOT_ID and parent <= MAX_ROBOT_ID and epoch != parent else None


def robot_wildcard(run: str, leaf: str) -> str:
    """``swarm/<run>/robot/*/<leaf>``: one leaf of every robot (e.g. all observation reports)."""
    if leaf not in ROBOT_LEAVES:
        raise KeyspaceError(f"robot key leaf {leaf!r} is not one of {ROBOT_LEAVES}")
    return f"{ROOT}/{validate_run(run)}/robot/*/{leaf}"


def truths_key(run: str) -> str:
    """``swarm/<run>/sim/truths``: every simulated robot's true pose after a step, in one message."""
    return f"{ROOT}/{validate_run(run)}/sim/truths"


def physics_key(run: str) -> str:
    """``swarm/<run>/sim/physics``: what the physical world did (docs/physics.md): true poses, contacts, stalls."""
    return f"{ROOT}/{validate_run(run)}/sim/physics"


def contact_key(run: str) -> str:
    """``swarm/<run>/sim/contact``: contacts of the robots' true bodies (simulation only)."""
    return f"{ROOT}/{validate_run(run)}/sim/contact"


def truth_wildcard(run: str) -> str:
    """``swarm/<run>/sim/truth/*``: every simulated robot's true pose."""
    return f"{ROOT}/{validate_run(run)}/sim/truth/*"


def alive_wildcard(run: str) -> str:
    """``swarm/<run>/alive/robot/*``: the liveliness tokens of every agent."""
    return f"{ROOT}/{validate_run(run)}/alive/robot/*"


def run_wildcard(run: str) -> str:
    """``swarm/<run>/**``: everything of one run (e.g. for the recorder)."""
    return f"{ROOT}/{validate_run(run)}/**"


def _parse_id(chunk: str, key: str) -> int:
    if not _ID.fullmatch(chunk) or int(chunk) > MAX_ROBOT_ID:
        raise KeyspaceError(f"key {key!r}: robot id {chunk!r} is not a decimal integer in [0, 2^63 - 1] without leading zeros")
    return int(chunk)


def parse_key(key: str) -> ParsedKey:
    """Split a concrete swarm key (no wildcards); anything else raises ``KeyspaceError``."""
    if not isinstance(key, str):
        raise KeyspaceError(f"key {key!r} is not a string")
    return _parse_str(key)


@functools.lru_cache(maxsize=8192)
def _parse_str(key: str) -> ParsedKey:
    """``parse_key`` of a string, cached: every message is parsed twice (its type, its header) and a run reuses
    a few keys per robot (an exception, for a key outside the key space, is not cached)."""
    parts = key.split("/")
    if len(parts) < 3 or parts[0] != ROOT:
        raise KeyspaceError(f"key {key!r} is not a swarm key (swarm/<run>/...)")
    run = parts[1]
    if not _RUN.fullmatch(run):
        raise KeyspaceError(f"key {key!r}: run id {run!r} is invalid")
    rest = parts[2:]
    if len(rest) == 3 and rest[0] == "robot" and rest[2] in ROBOT_LEAVES:
        return ParsedKey(run, "robot", _parse_id(rest[1], key), rest[2])
    if len(rest) == 2 and rest[0] == "coord" and rest[1] in COORD_LEAVES:
        return ParsedKey(run, "coord", None, rest[1])
    if len(rest) == 3 and rest[:2] == ["sim", "truth"]:
        return ParsedKey(run, "sim", _parse_id(rest[2], key), "truth")
    if rest == ["sim", "truths"]:
        return ParsedKey(run, "sim", None, "truths")
    if rest == ["sim", "contact"]:
        return ParsedKey(run, "sim", None, "contact")
    if rest == ["sim", "physics"]:
        return ParsedKey(run, "sim", None, "physics")
    if len(rest) == 3 and rest[:2] == ["alive", "robot"]:
        return ParsedKey(run, "alive", _parse_id(rest[2], key), "alive")
    if len(rest) == 3 and rest[0] == "link" and rest[2] == "stats" and _RUN.fullmatch(rest[1]):
        return ParsedKey(run, "link", None, "stats")
    if rest == ["estop"]:
        return ParsedKey(run, "estop", None, "estop")
    if rest == ["estop", "ack"]:
        return ParsedKey(run, "estop", None, "ack")
    if len(rest) == 4 and rest[:2] == ["alive", "coord"] and parse_coord_token(key) is not None:
        return ParsedKey(run, "alive", None, "alive")
    if len(rest) == 3 and rest[:2] == ["alive", "link"] and _RUN.fullmatch(rest[2]):
        return ParsedKey(run, "alive", None, "alive")
    raise KeyspaceError(f"key {key!r} is not in the swarm key space (see docs/protocol.md)")
