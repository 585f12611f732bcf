"""Recording and views of a run: the MCAP log, Foxglove scenes and live view, plot channels, ROS 2 export."""
