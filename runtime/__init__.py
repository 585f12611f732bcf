"""Shared layer of the swarm runtime: models, configuration, data types.

Everything here is used by every process (robot agents, coordinator, tools) and
imports nothing from ``robot_agent``, ``coordinator`` or ``swarm_cli``.
Units are SI throughout: metres, radians, seconds.
"""
