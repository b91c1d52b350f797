"""Wheel motion (docs/algorithm.md §3.3): the SRR-like rover's kinematics and trapezoidal move profiles."""
