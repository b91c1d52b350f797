"""`safer-hil experiment ...`: the paper's experiments and the project's own, each writing its results file."""
