"""The team mask keeps the ground round a robot whose ground is known (docs/algorithm.md §8.1)."""

from __future__ import annotations

import numpy as np

from fsw.core.map.body_mask import BodyBox, MaskConfig, TeamGeometry, team_mask


def _cov(n: int, sigma: float) -> np.ndarray:
    return np.tile(np.eye(3)[None] * sigma**2, (n, 1, 1))


def test_the_ground_round_a_robot_is_kept_and_the_robot_is_not() -> None:
    """An Anchorbot-like box lifted 0.15 m over its ground, with a 5 cm pose error: its grown
    volume and the sight lines past it reach the ground round it. With its ground known, the
    ground points outside its footprint stay; a point on the robot (inside its footprint), a
    flying pixel above the ground and a point of unknown error are still masked."""
    ground = np.zeros(3)
    box = BodyBox(np.array([0.0, 0.0, 0.3]), np.eye(3), np.array([0.35, 0.35, 0.15]), 0.05)
    eye = np.array([1.6, -1.2, 0.45])  # a Cliff-bot's head looking at it
    cfg = MaskConfig(margin_m=0.015, behind=1.0)
    p = np.array([
        [0.42, -0.3, 0.005],  # ground beside it, inside the grown box (3 sigma of pose: 15 cm)
        [-0.45, 0.3, 0.0],  # ground behind it: its sight line crosses the box
        [0.36, 0.0, 0.2],  # a flying pixel off its face, above the ground
        [0.3, 0.0, 0.005],  # its own lowest face (inside its footprint)
        [0.42, -0.3, 0.005],  # ground, but with an unknown (NaN) error
    ])
    cov = _cov(len(p), 0.01)
    cov[4] = np.nan
    without = team_mask(p, cov, TeamGeometry((box,), ()), cfg, eye=eye)
    assert without.tolist() == [True, True, True, True, True]
    known = BodyBox(box.center, box.R, box.half, box.sigma_m, ground)
    got = team_mask(p, cov, TeamGeometry((known,), ()), cfg, eye=eye)
    assert got.tolist() == [False, False, True, True, True]
    # the band is the point's own error along the normal: a 3 cm point 4 cm up is ground at
    # 1 sigma plus the margin only when its error is that large
    up = np.array([[0.42, -0.3, 0.04]])
    assert team_mask(up, _cov(1, 0.01), TeamGeometry((known,), ()), cfg, eye=eye).tolist() == [True]
    assert team_mask(up, _cov(1, 0.03), TeamGeometry((known,), ()), cfg, eye=eye).tolist() == [False]
    # a tilted robot: the plane it stands on, not the horizontal, bounds its ground
    a = np.radians(30.0)
    R = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(a), -np.sin(a)], [0.0, np.sin(a), np.cos(a)]])
    tilted = BodyBox(R @ np.array([0.0, 0.0, 0.3]), R, box.half, 0.01, ground)
    # on its plane, 5 cm below it, and 10 cm above it, just outside its footprint (inside its grown volume)
    pts = np.array([R @ np.array([0.0, -0.38, h]) for h in (0.0, -0.05, 0.1)])
    assert team_mask(pts, _cov(3, 0.005), TeamGeometry((BodyBox(tilted.center, R, box.half, 0.01),), ()), cfg,
                     eye=eye).all()
    assert team_mask(pts, _cov(3, 0.005), TeamGeometry((tilted,), ()), cfg, eye=eye).tolist() == [False, False, True]
