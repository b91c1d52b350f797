"""Core algorithms: pure functions and small classes on arrays (no I/O, no clock)."""
