"""Robot agent: one process per robot that executes open-loop commands through a driver
and publishes its neighbour observations. Builds on ``runtime``; never imports ``coordinator``.

``driver.py`` holds the driver interface and the simulated driver (the shared models
``runtime.models.motion`` and ``runtime.models.sensing``); ``gateway_driver.py`` drives a real
robot through its link process. ``host.py`` runs many agents in one process, ``link.py`` owns
a serial/radio port, and ``emulator.py`` emulates robots on pseudo-terminals.
"""
