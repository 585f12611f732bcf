"""Coordinator: centralized localization (topology fusion) and, later, anchor selection.

Builds on ``runtime``; never imports ``robot_agent``.
"""
