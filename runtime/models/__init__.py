"""The swarm's models: state, trajectories, motion and sensing, the simulated world, metrics (SI units)."""
