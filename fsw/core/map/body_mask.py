"""The team's own bodies and tethers kept out of the map (docs/algorithm.md §8.1).

A camera of either agent sees the other robots and the tethers; stereo measures them like
terrain. Before a view's points are fused they are tested against the team's known geometry
(:class:`TeamGeometry`): every robot as an oriented box at its known pose, every tether as a
polyline (anchor exit, contact points, attachment) with its radius. A point is masked when it
lies inside a shape grown by ``margin_m`` plus ``sigma`` times its own position error (the
square root of the largest variance of its covariance, which includes the camera pose's) and
the shape's own pose error ``shape_sigma_m`` (a robot known from a fix or its navigation).

A stereo point at a shape's outline can land anywhere between the shape and the surface behind
it, or between a lip in front of a robot and the robot (the matching window straddles both:
a "flying pixel"; a window that matches the other image's robot lands farther off). With the
camera's centre ``eye``, a point is also masked when its line of sight (for a robot: from the
camera out to ``behind`` times the point's range; a tether's known polyline may cut through
the ground it wraps, so not behind the point) passes through a shape grown by the margin, ``sigma`` times
the shape's pose error, and ``pixel_rad`` radians plus ``sigma`` times the point's error
across its line of sight per metre of its range, at the shape's range (the camera pose's error
turns the sight line; the window's half width in angle): what a camera sees just past a robot's outline or along a
tether, or just in front of one it hides, is not trusted as terrain. The camera's own robot
(a box within ``own_m`` of the camera) is rigid in the camera's frame: its sight test has
neither the pose term nor the extension.

A robot whose ground is known (``BodyBox.ground``: a point of the plane it stands on, its up
axis the plane's normal) keeps the ground round it: a point outside its footprint (grown by the
margin) and at or below that plane within the margin plus ``ground_sigma`` times its own error
along the normal is ground, whatever the two tests say. The robot stands above its ground and a
stereo point between its outline and the terrain behind lies above that terrain, so neither is
such a point; the pose error's growth of both tests otherwise takes a band of ground round the
robot (the tethers run over it).

A tether whose ground is known (``TetherLine.ground``: the ground's height under each point of its
polyline; a taut tether is the upper hull of the ground profile, so the ground under a segment lies
at or below the line between its ends' ground heights) keeps the ground under it the same way: a
point under the segment (horizontally within the tube's reach of it) whose height is at or below
that line (at its horizontal place along the segment) within ``ground_sigma`` times its own
vertical error (no margin: a window straddling the tether and the ground behind places its point a
few centimetres above that ground), and below the tether there by more than
its radius, the margin and ``sigma`` times that error, is ground, for that segment's tube and sight
test. Where the tether lies on its ground (a contact) nothing is kept; segments with an unknown end
(a face below a contact, whose concave parts the line spans in the air) keep nothing.
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
    ground: F64 | None = None  # a point of the ground plane it stands on (normal: its up axis), when known


def standing_box(ground: F64, yaw: float, body_points: F64, sigma_m: float = 0.0, below_m: float = 0.0) -> BodyBox:
    """A robot standing level at ``ground`` (its footprint centre on the ground, world) with
    heading ``yaw``: the box of its body-frame points ``(N, 3)`` (x forward, y left, z up from
    the ground; symmetric about the centre in x and y), reaching ``below_m`` under the ground
    (a ground height known only roughly)."""
    p = np.asarray(body_points, float).reshape(-1, 3)
    top = max(float(p[:, 2].max()), 0.0)
    half = np.array([np.abs(p[:, 0]).max(), np.abs(p[:, 1]).max(), 0.5 * (top + below_m)])
    c, s_ = np.cos(yaw), np.sin(yaw)
    R = np.array([[c, -s_, 0.0], [s_, c, 0.0], [0.0, 0.0, 1.0]])
    center = np.asarray(ground, float).reshape(3) + np.array([0.0, 0.0, 0.5 * (top - below_m)])
    return BodyBox(center, R, half, sigma_m)


# An Anchorbot as a mask knows it (its box is 0.6 x 0.5 x 0.4 m, any heading): from ANCHOR_LIFT_M above
# its ground to 0.45 m, so the mask's growth stays above the ground round it (the tethers start over that
# ground), which :attr:`BodyBox.ground` keeps.
ANCHOR_HALF_M = (0.35, 0.35, 0.15)
ANCHOR_LIFT_M = 0.15


def anchorbot_box(ground: F64, sigma_m: float) -> BodyBox:
    """An Anchorbot standing at its surveyed ground point ``ground`` (world, under its tether's
    exit), known to ``sigma_m``: the box from ``ANCHOR_LIFT_M`` above that ground up, any heading,
    with the ground round it kept."""
    g = np.asarray(ground, float).reshape(3)
    return BodyBox(g + np.array([0.0, 0.0, ANCHOR_LIFT_M + ANCHOR_HALF_M[2]]), np.eye(3),
                   np.asarray(ANCHOR_HALF_M, float), sigma_m, g)


@dataclass(frozen=True)
class TetherLine:
    """A tether: its polyline ``(K, 3)`` (K >= 2) and radius; ``ground``, when known, the ground's
    height ``(K,)`` under each point of the polyline (NaN: unknown there; module docstring)."""

    points: F64
    radius_m: float
    sigma_m: float = 0.0
    ground: F64 | None = None


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
    behind: float = 2.0  # the sight line is tested out to this multiple of the point's range
    behind_tether: float = 1.5  # the same for a tether
    own_m: float = 1.0  # a box the camera is this close to is its own robot's (a mast's camera too)
    ground_sigma: float = 1.0  # a point within the margin and this many sigma of a robot's ground is ground
    # the band above a robot's ground kept with those sigma (None: the margin); a far camera's 1 sigma
    # is centimetres, and a window straddling a robot's outline and the ground behind lies that high
    ground_band_m: float | None = None


def point_sigma(cov: F64) -> F64:
    """A conservative per-point position deviation: the square root of the largest diagonal
    variance of each ``(N, 3, 3)`` covariance (NaN treated as infinite)."""
    d = np.diagonal(np.asarray(cov, float), axis1=1, axis2=2)
    return np.asarray(np.sqrt(np.nan_to_num(d, nan=np.inf).max(axis=1)), float)


def lateral_sigma(xyz: F64, cov: F64, eye: F64) -> F64:
    """Each point's position error across its line of sight from ``eye``: the root of the
    covariance's trace less its variance along the sight line (both cross directions)."""
    d = np.asarray(xyz, float) - eye
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-9)
    c = np.nan_to_num(np.asarray(cov, float), nan=np.inf, posinf=np.inf)
    along = np.einsum("ni,nij,nj->n", d, c, d)
    with np.errstate(invalid="ignore"):
        lat = np.trace(c, axis1=1, axis2=2) - along
    return np.asarray(np.sqrt(np.nan_to_num(np.maximum(lat, 0.0), nan=np.inf)), float)


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
    far = far_t = p
    lat = np.zeros(n)  # per metre of range: the sight line's error grows from the camera
    if e is not None:
        far = e + cfg.behind * (p - e)
        far_t = e + cfg.behind_tether * (p - e)
        if cov is not None:
            lat = cfg.sigma * lateral_sigma(p, cov, e) / np.maximum(np.linalg.norm(p - e, axis=1), 1e-3)
    for box in team.boxes:
        g = grow + cfg.sigma * box.sigma_m
        local = (p - box.center) @ box.R
        hit = (np.abs(local) <= box.half[None, :] + g[:, None]).all(axis=1)
        if e is not None:
            g0 = cfg.margin_m + cfg.sigma * box.sigma_m
            if (np.abs((e - box.center) @ box.R) <= box.half + cfg.own_m).all():
                # the camera's own robot: rigid in the camera's frame, no pose error between them
                hit |= _sight_through_box(e, p, box, g0, cfg.pixel_rad)
            else:
                hit |= _sight_through_box(e, far, box, g0, cfg.pixel_rad + lat)
        if box.ground is not None and cov is not None:
            hit &= ~_at_ground(p, cov, box, cfg)
        out |= hit
    for t in team.tethers:
        pts = np.asarray(t.points, float)
        if pts.ndim != 2 or pts.shape[0] < 2:
            raise ValueError("a tether needs at least two points")
        gz = None if t.ground is None or cov is None else np.asarray(t.ground, float).reshape(-1)
        if gz is not None and len(gz) != len(pts):
            raise ValueError("a tether's ground needs one height per point of its polyline")
        g = grow + t.radius_m + cfg.sigma * t.sigma_m
        for k, (a, b) in enumerate(zip(pts[:-1], pts[1:], strict=True)):
            ab = b - a
            ll = float(ab @ ab)
            s = np.clip(((p - a) @ ab) / ll, 0.0, 1.0) if ll > 0 else np.zeros(n)
            d = np.linalg.norm(p - (a + s[:, None] * ab), axis=1)
            hit = d <= g
            if e is not None:
                dist, rng = _segment_distance(e, far_t, a, b)
                hit |= dist <= cfg.margin_m + t.radius_m + cfg.sigma * t.sigma_m + cfg.pixel_rad * rng
            if gz is not None and cov is not None and np.isfinite(gz[k : k + 2]).all():
                hit &= ~_under_segment(p, cov, a, b, (float(gz[k]), float(gz[k + 1])), t.radius_m, g, cfg)
            out |= hit
    return out


def _under_segment(p: F64, cov: F64, a: F64, b: F64, ground: tuple[float, float], radius_m: float,
                   reach: F64, cfg: MaskConfig) -> B:
    """Points of the ground under the tether segment ``a b``: horizontally between its ends and
    within ``reach`` (per point: the tube's) of its horizontal line, at or below its ground (heights
    ``ground`` under its ends, linear between them) within ``ground_sigma`` times their own vertical
    error (no margin: a stereo point between the tether and the ground behind it, a window
    straddling both, lies a few centimetres above that ground), and below the tether there by
    more than its radius, the margin and ``sigma`` times that error (where the tether lies on its
    ground, at a contact, a point on it and one of the ground cannot be told apart: neither is
    kept). The ground seen past the tether
    farther out (its shadow) is not under it. NaN: not ground."""
    h = (b - a)[:2]
    hh = float(h @ h)
    if hh <= 0:
        return np.zeros(len(p), bool)
    rel = p[:, :2] - a[:2]
    s = (rel @ h) / hh
    side = np.abs(rel[:, 0] * h[1] - rel[:, 1] * h[0]) / np.sqrt(hh)
    zg = ground[0] + s * (ground[1] - ground[0])
    zt = a[2] + s * (b[2] - a[2])
    c = np.nan_to_num(np.asarray(cov, float)[:, 2, 2], nan=np.inf, posinf=np.inf)
    sz = np.sqrt(np.maximum(c, 0.0))
    with np.errstate(invalid="ignore"):
        low = p[:, 2] <= zg + cfg.ground_sigma * sz
        clear = p[:, 2] < zt - radius_m - cfg.margin_m - cfg.sigma * sz
        under = (s >= 0.0) & (s <= 1.0) & (side <= reach)
        return np.asarray(np.isfinite(sz) & under & low & clear, bool)


def _at_ground(p: F64, cov: F64, box: BodyBox, cfg: MaskConfig) -> B:
    """Points of the ground round ``box``: outside its footprint grown by the margin (not by its
    pose error: that growth would take the band this keeps), and at or below the ground plane it stands on
    (``box.ground``, normal its up axis) within the margin plus ``sigma`` times their own error
    along the normal (NaN: not ground). A robot stands above its ground, and a point between its
    outline and the terrain behind lies above that terrain."""
    assert box.ground is not None
    n = box.R[:, 2]
    c = np.nan_to_num(np.asarray(cov, float), nan=np.inf, posinf=np.inf)
    with np.errstate(invalid="ignore"):
        sn = np.sqrt(np.maximum(np.einsum("i,nij,j->n", n, c, n), 0.0))
    band = cfg.margin_m if cfg.ground_band_m is None else cfg.ground_band_m
    low = np.isfinite(sn) & ((p - box.ground) @ n <= band + cfg.ground_sigma * np.nan_to_num(sn, nan=np.inf))
    local = (p - box.center) @ box.R
    out = (np.abs(local[:, :2]) > box.half[None, :2] + cfg.margin_m).any(axis=1)
    return np.asarray(low & out, bool)


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


def _sight_through_box(e: F64, p: F64, box: BodyBox, grow: float, pixel_rad: float | F64) -> B:
    """Sight lines ``e -> p_i`` that pass through ``box`` grown by ``grow`` plus ``pixel_rad``
    (one value or one per line) times the range of the box (slab test in the box frame); none
    when ``e`` is inside the box grown by ``grow``."""
    rng = float(np.linalg.norm(box.center - e))
    pr = np.broadcast_to(np.asarray(pixel_rad, float), (len(p),))
    half = box.half[None, :] + (grow + pr * rng)[:, None]
    o = (e - box.center) @ box.R
    if (np.abs(o) <= box.half + grow).all():
        return np.zeros(len(p), bool)  # a camera on the box itself: only the box's own volume is masked
    d = (p - e) @ box.R
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (-half - o[None, :]) / d
        t2 = (half - o[None, :]) / d
    lo = np.where(np.isnan(t1), -np.inf, np.minimum(t1, t2))
    hi = np.where(np.isnan(t1), np.inf, np.maximum(t1, t2))
    inside_axis = np.abs(o)[None, :] <= half
    lo = np.where(d == 0, np.where(inside_axis, -np.inf, np.inf), lo)
    hi = np.where(d == 0, np.where(inside_axis, np.inf, -np.inf), hi)
    t_in = lo.max(axis=1)
    t_out = hi.min(axis=1)
    return np.asarray((t_in <= t_out) & (t_out >= 0.0) & (t_in <= 1.0), bool)
