"""The team's own bodies and tethers kept out of the map (docs/algorithm.md §8.1).

A camera of either agent sees the other robots and the tethers; stereo measures them like
terrain. Before a view's points are fused they are tested against the team's known geometry
(:class:`TeamGeometry`): every robot as an oriented box at its known pose, every tether as a
polyline (anchor exit, contact points, attachment) with its radius. A point is masked when it
lies inside a shape grown by ``margin_m`` plus ``sigma`` times its own position error (the
square root of the largest variance of its covariance, which includes the camera pose's) and
the shape's own pose error ``shape_sigma_m`` (a robot known from a fix or its navigation).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]
B = NDArray[np.bool_]


@dataclass(frozen=True)
class BodyBox:
    """A robot: an oriented box (centre, body-to-world rotation, half sizes) and the standard
    deviation of its known position."""

    center: F64
    R: F64
    half: F64
    sigma_m: float = 0.0


@dataclass(frozen=True)
class TetherLine:
    """A tether: its polyline ``(K, 3)`` (K >= 2) and radius."""

    points: F64
    radius_m: float
    sigma_m: float = 0.0


@dataclass(frozen=True)
class TeamGeometry:
    """What a mask needs: the team's robots and tethers at their known poses."""

    boxes: tuple[BodyBox, ...] = ()
    tethers: tuple[TetherLine, ...] = ()


@dataclass(frozen=True)
class MaskConfig:
    margin_m: float = 0.04
    sigma: float = 3.0


def point_sigma(cov: F64) -> F64:
    """A conservative per-point position deviation: the square root of the largest diagonal
    variance of each ``(N, 3, 3)`` covariance (NaN treated as infinite)."""
    d = np.diagonal(np.asarray(cov, float), axis1=1, axis2=2)
    return np.asarray(np.sqrt(np.nan_to_num(d, nan=np.inf).max(axis=1)), float)


def team_mask(xyz: F64, cov: F64 | None, team: TeamGeometry, cfg: MaskConfig | None = None) -> B:
    """True for each world point ``(N, 3)`` on a robot or a tether of ``team`` (module docstring);
    ``cov`` ``(N, 3, 3)`` the points' covariance (None: the margin alone)."""
    cfg = cfg or MaskConfig()
    p = np.asarray(xyz, float).reshape(-1, 3)
    n = len(p)
    grow = np.full(n, cfg.margin_m) if cov is None else cfg.margin_m + cfg.sigma * point_sigma(cov)
    out = np.zeros(n, bool)
    if n == 0:
        return out
    for box in team.boxes:
        local = np.abs((p - box.center) @ box.R)
        g = grow + cfg.sigma * box.sigma_m
        out |= (local <= box.half[None, :] + g[:, None]).all(axis=1)
    for t in team.tethers:
        pts = np.asarray(t.points, float)
        if pts.ndim != 2 or pts.shape[0] < 2:
            raise ValueError("a tether needs at least two points")
        g = grow + t.radius_m + cfg.sigma * t.sigma_m
        for a, b in zip(pts[:-1], pts[1:], strict=True):
            ab = b - a
            ll = float(ab @ ab)
            s = np.clip(((p - a) @ ab) / ll, 0.0, 1.0) if ll > 0 else np.zeros(n)
            d = np.linalg.norm(p - (a + s[:, None] * ab), axis=1)
            out |= d <= g
    return out
