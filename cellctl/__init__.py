"""cellctl: vision controller of a robotic shoe-sole gluing cell."""

__version__ = "0.1.0"
