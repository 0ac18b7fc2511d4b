"""The reliability suite: faults, hostile input, security, soak, shutdown and restart."""
