"""The cell service: configuration, the cycle (a pure function), the daemon that wires cameras, the cycle,
the journal and the PLC link together, artifacts and systemd notification."""
