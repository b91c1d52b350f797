"""Localization (docs/algorithm.md §5, §5.1, §8): camera pose by PnP with covariance, the Cliff-bot from its
fiducials, dead reckoning, attitude, and the registration's correction fed back to the rover's pose."""
