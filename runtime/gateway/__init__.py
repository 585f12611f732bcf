"""The gateway's side of real robots: the frame protocol and the gateway configuration file."""
