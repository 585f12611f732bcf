"""The wire between processes: the Zenoh key space, the typed messages, sessions and pub/sub."""
