"""The ``swarm`` command line: the top layer, built on ``runtime``, ``robot_agent`` and ``coordinator``."""
