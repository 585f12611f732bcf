"""Coordinator: centralized localization (topology fusion), anchor selection, and the executor
that drives a swarm backend (in-process simulation or Zenoh agents) along a trajectory.

Builds on ``runtime``; never imports ``robot_agent``.
"""
