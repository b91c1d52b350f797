"""The team's own bodies and tethers kept out of the map (docs/algorithm.md §8.1).

A camera of either agent sees the other robots and the tethers; stereo measures them like
terrain. Before a view's points are fused they are tested against the team's known geometry
(:class:`TeamGeometry`): every robot as an oriented box at its known pose, every tether as a
polyline (anchor exit, contact points, attachment) with its radius. A point is masked when it
lies inside a shape grown by ``margin_m`` plus ``sigma`` times its own position error (the
square root of the largest variance of its covariance, which includes the camera pose's) and
the shape's own pose error ``shape_sigma_m`` (a robot known from a fix or its navigation).

A stereo point at a shape's outline can land anywhere between the shape and the ground behind
it (the matching window straddles both: a "flying pixel"). With the camera's centre ``eye``,
a point is also masked when its line of sight passes through a shape grown by the margin plus
``pixel_rad`` radians at that range (the window's half width in angle): what a camera sees
just past a robot's outline or along a tether is not trusted as terrain.
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
    pixel_rad: float = 0.01  # the line-of-sight test's growth per metre of range (about 3 px at f = 300 px)


def point_sigma(cov: F64) -> F64:
    """A conservative per-point position deviation: the square root of the largest diagonal
    variance of each ``(N, 3, 3)`` covariance (NaN treated as infinite)."""
    d = np.diagonal(np.asarray(cov, float), axis1=1, axis2=2)
    return np.asarray(np.sqrt(np.nan_to_num(d, nan=np.inf).max(axis=1)), float)


def team_mask(xyz: F64, cov: F64 | None, team: TeamGeometry, cfg: MaskConfig | None = None,
              eye: F64 | None = None) -> B:
    """True for each world point ``(N, 3)`` on a robot or a tether of ``team`` or, with the
    camera centre ``eye``, seen past one (module docstring); ``cov`` ``(N, 3, 3)`` the points'
    covariance (None: the margin alone)."""
    cfg = cfg or MaskConfig()
    p = np.asarray(xyz, float).reshape(-1, 3)
    n = len(p)
    grow = np.full(n, cfg.margin_m) if cov is None else cfg.margin_m + cfg.sigma * point_sigma(cov)
    out = np.zeros(n, bool)
    if n == 0:
        return out
    e = None if eye is None else np.asarray(eye, float).reshape(3)
    for box in team.boxes:
        g = grow + cfg.sigma * box.sigma_m
        local = (p - box.center) @ box.R
        out |= (np.abs(local) <= box.half[None, :] + g[:, None]).all(axis=1)
        if e is not None:
            out |= _sight_through_box(e, p, box, cfg.margin_m + cfg.sigma * box.sigma_m, cfg.pixel_rad)
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
            if e is not None:
                dist, rng = _segment_distance(e, p, a, b)
                out |= dist <= cfg.margin_m + t.radius_m + cfg.sigma * t.sigma_m + cfg.pixel_rad * rng
    return out


def _segment_distance(e: F64, p: F64, a: F64, b: F64) -> tuple[F64, F64]:
    """Closest distance between each sight line ``e -> p_i`` and the segment ``a b``, and the
    range from ``e`` at which it occurs."""
    d1 = p - e  # (N, 3)
    d2 = b - a
    r = e - a
    aa = np.einsum("ij,ij->i", d1, d1)
    ee = float(d2 @ d2)
    f = float(d2 @ r)
    c = d1 @ r
    bb = d1 @ d2
    den = aa * ee - bb * bb
    with np.errstate(invalid="ignore", divide="ignore"):
        s = np.where(den > 1e-12, np.clip((bb * f - c * ee) / den, 0.0, 1.0), 0.0)
        t = np.clip((bb * s + f) / ee, 0.0, 1.0) if ee > 0 else np.zeros(len(p))
        s = np.where(aa > 0, np.clip((bb * t - c) / aa, 0.0, 1.0), 0.0)
    q1 = e + s[:, None] * d1
    q2 = a + t[:, None] * d2
    return np.linalg.norm(q1 - q2, axis=1), np.sqrt(aa) * s


def _sight_through_box(e: F64, p: F64, box: BodyBox, grow: float, pixel_rad: float) -> B:
    """Sight lines ``e -> p_i`` that pass through ``box`` grown by ``grow`` plus ``pixel_rad``
    times the range of the box (slab test in the box frame); none when ``e`` is inside it."""
    rng = float(np.linalg.norm(box.center - e))
    half = box.half + grow + pixel_rad * rng
    o = (e - box.center) @ box.R
    if (np.abs(o) <= half).all():  # a camera on the box itself: only the box's own volume is masked
        return np.zeros(len(p), bool)
    d = (p - e) @ box.R
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (-half[None, :] - o[None, :]) / d
        t2 = (half[None, :] - o[None, :]) / d
    lo = np.where(np.isnan(t1), -np.inf, np.minimum(t1, t2))
    hi = np.where(np.isnan(t1), np.inf, np.maximum(t1, t2))
    inside_axis = np.abs(o)[None, :] <= half[None, :]
    lo = np.where(d == 0, np.where(inside_axis, -np.inf, np.inf), lo)
    hi = np.where(d == 0, np.where(inside_axis, np.inf, -np.inf), hi)
    t_in = lo.max(axis=1)
    t_out = hi.min(axis=1)
    return np.asarray((t_in <= t_out) & (t_out >= 0.0) & (t_in <= 1.0), bool)
