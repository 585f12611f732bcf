"""The coordinator as a networked node: the executor's backend over Zenoh (``zenoh_backend``), the coordinator
process of a distributed run with its standby and checkpoints (``process``), and the run-wide stop (``stop``).

The algorithm core (``coordinator.executor``, ``coordinator.selection``, ``coordinator.localization``,
``coordinator.plan``, ``coordinator.clearance``) knows nothing of the network; this package builds on it.
"""
