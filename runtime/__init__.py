"""Shared layer of the swarm runtime, by concern (each folder imports only from the ones before it).

- ``runtime.errors``: the error hierarchy every process raises; ``runtime.paths``: path arguments (``str`` or ``os.PathLike``).
- ``runtime.models``: state, trajectories, motion and sensing models, the simulated world, metrics.
- ``runtime.wire``: the Zenoh key space, typed msgpack messages, sessions and pub/sub.
- ``runtime.gateway``: the gateway <-> robot frame protocol and the gateway configuration file.
- ``runtime.recording``: the MCAP log of a run and its views (Foxglove, plot channels, ROS 2).

Everything here is used by every process (robot agents, coordinator, tools) and
imports nothing from ``robot_agent``, ``coordinator`` or ``swarm_cli``.
Units are SI throughout: metres, radians, seconds.
"""
