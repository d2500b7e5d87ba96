"""Client side of a mission: the goal client the CLI uses and PerchCommander, the non-blocking Python API."""
