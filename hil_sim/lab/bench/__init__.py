"""`safer-hil bench ...`: benchmarks of the flown code paths."""
