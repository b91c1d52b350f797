"""Stereo (docs/algorithm.md §4, §1.2): rectification, dense matching to points with covariance, per-pixel
quality, calibration of the pair, occlusion lips."""
