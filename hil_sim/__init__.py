"""Hardware-in-the-loop simulator: world truth, hardware models, experiments."""
