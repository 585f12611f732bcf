"""Robot agent: one process per robot that executes open-loop commands through a driver
and publishes its neighbour observations. Builds on ``runtime``; never imports ``coordinator``.

The agent process and its drivers arrive with the distributed-runtime issue; the models
they will run (``runtime.models.motion``, ``runtime.models.sensing``) are already shared.
"""
