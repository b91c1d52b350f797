"""Protocols: sans-I/O state machines for the inter-robot link; the MAVLink adapter."""
