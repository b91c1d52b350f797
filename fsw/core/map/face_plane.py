"""The face plane: its frame and its fit to the steep cells of a gravity map (docs/algorithm.md §8.1).

:class:`FaceFrame` is the plane with its axes; :func:`fit_face_plane` finds it among the steep
mapped cells of a gravity grid; :func:`face_band` bounds the face map on it (along the strike
and along the dip). The steep cells of a cliff scene are not all face: a rock's
sides are steep and face every way, the jumble's rocks stand out of the face, the floor's rocks
stand on the floor, and early in a mission the face itself may be almost unmapped (from the
plateau the RECON-bot looks down a face at grazing incidence). The fit is therefore a consensus
of cells that lie on one steep plane *and* fall the way that plane falls, and it refuses a plane
whose cells do not span a face (a few rock sides that happen to line up), saying why, so the
caller tries again when the map holds more of the face.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fsw.core.map.elevation_map import ElevationMap

F64 = NDArray[np.float64]
B = NDArray[np.bool_]


@dataclass(frozen=True)
class FaceFrame:
    """The fitted face plane: origin and axes (columns ``e_u, e_v, e_n`` of ``R``)."""

    origin: F64
    R: F64

    @staticmethod
    def from_normal(origin: F64, normal: F64) -> FaceFrame:
        """The frame of the plane through ``origin`` with ``normal`` (turned out of the face:
        ``e_n . z > 0``); ``e_u`` horizontal. A vertical or horizontal normal is refused."""
        n = np.asarray(normal, float)
        n = n / np.linalg.norm(n)
        if n[2] < 0:
            n = -n
        h = float(np.hypot(n[0], n[1]))
        if not (1e-3 < h < 1.0 - 1e-6) or not np.isfinite(n).all():
            raise ValueError(f"a face plane needs a normal neither vertical nor horizontal, got {n}")
        eu = np.cross([0.0, 0.0, 1.0], n)
        eu /= np.linalg.norm(eu)
        ev = np.cross(n, eu)
        return FaceFrame(np.asarray(origin, float).reshape(3), np.column_stack([eu, ev, n]))

    @property
    def normal(self) -> F64:
        return np.asarray(self.R[:, 2], float)

    @property
    def slope_deg(self) -> float:
        """The plane's slope: the angle between its normal and the vertical."""
        return float(np.degrees(np.arccos(np.clip(self.R[2, 2], -1.0, 1.0))))

    def to_face(self, p: F64) -> F64:
        """World points ``(N, 3)`` to face coordinates ``(u, v, w)``."""
        return np.asarray((np.asarray(p, float) - self.origin) @ self.R, float)

    def to_world(self, q: F64) -> F64:
        return np.asarray(np.asarray(q, float) @ self.R.T + self.origin, float)

    def cov_to_face(self, cov: F64) -> F64:
        """Covariances ``(N, 3, 3)`` from the world to the face frame: ``R^T P R``."""
        return np.asarray(np.einsum("ji,njk,kl->nil", self.R, np.asarray(cov, float), self.R), float)

    def plane_z(self, x: F64, y: F64) -> F64:
        """The plane's height over ``(x, y)``."""
        n, o = self.normal, self.origin
        return np.asarray(o[2] - (n[0] * (np.asarray(x) - o[0]) + n[1] * (np.asarray(y) - o[1])) / n[2], float)


def steep_points(gravity: ElevationMap, min_slope_deg: float = 45.0) -> tuple[F64, F64]:
    """The centres ``(N, 3)`` of the mapped cells of ``gravity`` steeper than ``min_slope_deg``
    and their downhill directions ``(N, 2)`` (unit vectors, ``-grad z / |grad z|``)."""
    g = gravity.grid
    gy, gx = np.gradient(gravity.z, g.cell)
    slope = np.hypot(gx, gy)
    with np.errstate(invalid="ignore"):
        steep = gravity.mapped & (slope > np.tan(np.radians(min_slope_deg)))
    X, Y = g.centers()
    down = -np.column_stack([gx[steep], gy[steep]]) / slope[steep][:, None]
    return np.column_stack([X[steep], Y[steep], gravity.z[steep]]), down


def on_plane(cells: F64, down: F64, origin: F64, normal: F64, inlier_m: float, agree_cos: float) -> B:
    """The cells within ``inlier_m`` of the plane through ``origin`` with unit ``normal`` (``e_n .
    z > 0``) whose downhill direction lies within ``arccos agree_cos`` of the plane's (the
    horizontal part of its normal): a rock's side that faces another way is not the face, however
    near the plane it stands."""
    dist = np.abs((cells - origin) @ normal)
    dip = normal[:2] / max(float(np.hypot(normal[0], normal[1])), 1e-12)
    return np.asarray((dist <= inlier_m) & (down @ dip >= agree_cos), bool)


def _ransac_plane(cells: F64, down: F64, inlier_m: float, tries: int, lo_deg: float, hi_deg: float,
                  agree_cos: float) -> B:
    """The cells on the plane through three of them, sloping ``lo_deg`` to ``hi_deg``, with the
    most cells :func:`on_plane` (triples drawn from a fixed seed). Raises ``ValueError`` when no
    triple spans such a plane."""
    rng = np.random.default_rng(0)
    tri = rng.integers(0, len(cells), (tries, 3))
    a, b, c = cells[tri[:, 0]], cells[tri[:, 1]], cells[tri[:, 2]]
    n = np.cross(b - a, c - a)
    ln = np.linalg.norm(n, axis=1)
    ok = ln > 1e-9
    n = n[ok] / ln[ok, None]
    n = np.where(n[:, 2:3] < 0, -n, n)
    slope = np.degrees(np.arccos(np.clip(n[:, 2], -1.0, 1.0)))
    steep = (slope >= lo_deg) & (slope <= hi_deg)
    if not steep.any():
        raise ValueError(f"no plane through the steep cells slopes {lo_deg:.0f} to {hi_deg:.0f} deg")
    n, a = n[steep], a[ok][steep]
    dip = n[:, :2] / np.hypot(n[:, 0], n[:, 1])[:, None]
    dist = np.abs(cells @ n.T - np.sum(a * n, axis=1))
    votes = (dist <= inlier_m) & (down @ dip.T >= agree_cos)
    return np.asarray(votes[:, int(np.argmax(votes.sum(axis=0)))], bool)


def fit_face_plane(gravity: ElevationMap, min_slope_deg: float = 45.0, min_cells: int = 50,
                   inlier_m: float = 0.15, tries: int = 1000, plane_slope_deg: float = 55.0,
                   agree_deg: float = 45.0, min_span_m: float = 1.0) -> FaceFrame:
    """The face plane, from the steep mapped cells of ``gravity`` (:func:`steep_points`).

    RANSAC from a fixed seed over planes through three steep cells, sloping ``plane_slope_deg``
    to 89 deg: the plane with the most cells :func:`on_plane` (within ``inlier_m`` and falling
    within ``agree_deg`` of the plane's own downhill direction; a rock's sides are steep too, but
    short and turned every way), then the total least-squares plane of those cells, its cells
    taken again, three times. Origin: their centroid. The strike (``e_u``) is the plane's
    horizontal line.

    The refined plane may be less steep than ``plane_slope_deg``: a face broken by ledges falls
    less steeply, lip to foot, than between its ledges, and the face map's plane is that of the
    whole face. Raises ``ValueError`` (the caller fits again when the map holds more) with fewer
    than ``min_cells`` steep cells or cells on the plane, a plane that ends less steep than the
    steep cells themselves (``min_slope_deg``), or cells on it spanning less than ``min_span_m`` along the strike or
    the dip (between their 5th and 95th percentiles): the sides of a few rocks that line up, or
    one strip of the face, whose strike or slope the cells do not hold."""
    cells, down = steep_points(gravity, min_slope_deg)
    if len(cells) < min_cells:
        raise ValueError(f"only {len(cells)} mapped cells steeper than {min_slope_deg} deg: no face to fit")
    agree_cos = float(np.cos(np.radians(agree_deg)))
    inl = _ransac_plane(cells, down, inlier_m, tries, plane_slope_deg, 89.0, agree_cos)
    normal = np.zeros(3)
    centre = np.zeros(3)
    for _ in range(3):
        if int(inl.sum()) < min_cells:
            raise ValueError(f"only {int(inl.sum())} steep cells on one plane: no face to fit")
        centre = cells[inl].mean(axis=0)
        _, _, vt = np.linalg.svd(cells[inl] - centre, full_matrices=False)
        normal = vt[2] if vt[2][2] >= 0 else -vt[2]
        inl = on_plane(cells, down, centre, normal, inlier_m, agree_cos)
    if int(inl.sum()) < min_cells:
        raise ValueError(f"only {int(inl.sum())} steep cells on one plane: no face to fit")
    slope = float(np.degrees(np.arccos(np.clip(normal[2], -1.0, 1.0))))
    if slope < min_slope_deg:
        raise ValueError(f"the steep cells' plane slopes {slope:.0f} deg, under {min_slope_deg:.0f}: "
                         "no face to fit")
    frame = FaceFrame.from_normal(centre, normal)
    q = frame.to_face(cells[inl])
    for axis, name in ((0, "strike"), (1, "dip")):
        lo, hi = np.percentile(q[:, axis], [5.0, 95.0])
        if hi - lo < min_span_m:
            raise ValueError(f"the {int(inl.sum())} steep cells on the best plane span {hi - lo:.2f} m along its "
                             f"{name}, under {min_span_m:.2f}: not yet a face")
    return frame


def face_band(gravity: ElevationMap, frame: FaceFrame, min_slope_deg: float = 45.0,
              inlier_m: float = 0.15, margin_m: float = 0.3) -> tuple[F64, F64]:
    """``((u_min, u_max), (v_min, v_max))`` of the face map. Along the strike, the gravity grid's
    whole extent (its corners on the plane). Along the dip, from ``margin_m`` (vertical) above
    the floor to ``margin_m`` below the plateau, where the plane meets their heights (the
    medians of the mapped gentle cells out in front of the plane and below its centre, and of
    those behind it and above); the transitions stay in the gravity grid, where the ground
    turns away from the plane. Without a floor or a plateau mapped, that end is the 1st (99th)
    percentile of the steep cells within ``inlier_m`` of the plane."""
    q = frame.to_face(steep_points(gravity, min_slope_deg)[0])
    q = q[np.abs(q[:, 2]) <= inlier_m]
    if len(q) == 0:
        raise ValueError("no steep mapped cells on the plane")
    x0, x1, y0, y1 = gravity.grid.extent
    cx, cy = np.array([x0, x1, x1, x0]), np.array([y0, y0, y1, y1])
    corners = frame.to_face(np.column_stack([cx, cy, frame.plane_z(cx, cy)]))
    u = np.array([corners[:, 0].min(), corners[:, 0].max()])
    v = np.percentile(q[:, 1], [1.0, 99.0])
    g = gravity.grid
    gy, gx = np.gradient(gravity.z, g.cell)
    with np.errstate(invalid="ignore"):
        gentle = gravity.mapped & (np.hypot(gx, gy) < np.tan(np.radians(min_slope_deg)))
    X, Y = g.centers()
    z = gravity.z[gentle]
    qg = frame.to_face(np.column_stack([X[gentle], Y[gentle], z]))
    ev_z = float(frame.R[2, 1])
    floor = (qg[:, 2] > 0) & (qg[:, 1] < 0)
    top = (qg[:, 2] < 0) & (qg[:, 1] > 0)
    if floor.sum() >= 10:
        v[0] = max(v[0], (float(np.median(z[floor])) + margin_m - frame.origin[2]) / ev_z)
    if top.sum() >= 10:
        v[1] = min(v[1], (float(np.median(z[top])) - margin_m - frame.origin[2]) / ev_z)
    if v[1] <= v[0]:
        raise ValueError("the face band is empty")
    return u, np.asarray(v, float)


def equal_memory_cell(gravity_cell_m: float, slope_deg: float) -> float:
    """The face cell side with as many cells over a face of ``slope_deg`` as the gravity grid's
    over its horizontal footprint: ``c_g / sqrt(cos a)`` (the strike is common, the dip is
    ``1 / cos a`` longer)."""
    return gravity_cell_m / math.sqrt(max(math.cos(math.radians(slope_deg)), 1e-3))
