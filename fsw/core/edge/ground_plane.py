"""The plane of the ground the rover stands on, from the elevation map (docs/algorithm.md §2).

The edge (``fsw.core.edge.edge``) is where the ground drops more than a step below the rover's
plateau. On level ground the plateau is "within a few cm of the rover's ground height"; on
sloped ground (issue 13: the generated terrains slope up to 12 deg, and until the rover's
attitude enters the pose chain the map is also tilted by it) that band shrinks to a strip
across the slope. The plateau's plane, fitted around the rover, serves both cases.

Rolling ground (a few cm of relief over metres, like the generated terrains' ``relief_m``)
leaves a plane's band in patches: the plateau then breaks into pieces whose borders are not
the edge, and the edge beside them goes unseen. :func:`ground_surface` bends the plane to
follow such ground: the residual heights of the cells near the surface, smoothed over
``surface_scale_m`` (a normalized Gaussian convolution: only plateau cells contribute, so the
surface near the lip is extrapolated from the plateau, never pulled down into the drop), in
three rounds with a band narrowing from ``3 * plateau_tol_m`` to ``plateau_tol_m``. Far from
any plateau cell the bend fades to the plane.
"""

from __future__ import annotations

from typing import Protocol

import cv2
import numpy as np
from numpy.typing import NDArray

from fsw.core.map.elevation_map import ElevationMap


class PlaneLimits(Protocol):
    """The ``[edge]`` keys the plane fit reads (``fsw.core.edge.edge.EdgeConfig``)."""

    @property
    def plateau_tol_m(self) -> float: ...

    @property
    def min_region_cells(self) -> int: ...

    @property
    def max_slope_deg(self) -> float: ...

    @property
    def surface_scale_m(self) -> float: ...


F64 = NDArray[np.float64]
SURFACE_MIN_WEIGHT = 0.05  # below this share of plateau cells nearby, the bend fades to the plane


def ground_plane(emap: ElevationMap, ground_z_m: float, seed_xy: tuple[float, float],
                 cfg: PlaneLimits) -> F64:
    """The rover's ground as a plane near ``(seed_xy, ground_z_m)`` (the height the pose chain
    gives the ground under the rover), per map cell: fitted (least squares in slope and
    height, slope at most ``max_slope_deg``; the height absorbs a few cm of pose-chain drift)
    to the mapped cells near the plateau
    within growing radii (0.75, 1.5, 3 m), each round keeping the cells within
    ``3 * plateau_tol_m`` of the last plane. On level ground it stays level; on a sloped plateau
    (or a map tilted by the rover's attitude) the safe region and the drop follow the slope."""
    g = emap.grid
    X, Y = g.centers()
    dx, dy = X - seed_xy[0], Y - seed_xy[1]
    z = emap.z
    ok = emap.mapped & np.isfinite(z)
    a = b = c = 0.0
    for radius in (0.75, 1.5, 3.0):
        rel = z - ground_z_m - c - a * dx - b * dy
        near = ok & (dx * dx + dy * dy <= radius * radius)
        sel = near & (np.abs(np.where(ok, rel, np.inf)) <= 3.0 * cfg.plateau_tol_m)
        if sel.sum() < cfg.min_region_cells:
            continue
        m = np.column_stack([dx[sel], dy[sel], np.ones(int(sel.sum()))])
        a, b, c = np.linalg.lstsq(m, z[sel] - ground_z_m, rcond=None)[0]
        slope = float(np.hypot(a, b))
        cap = float(np.tan(np.radians(cfg.max_slope_deg)))
        if slope > cap:
            a, b = a * cap / slope, b * cap / slope
    return np.asarray(ground_z_m + c + a * dx + b * dy, np.float64)


def ground_surface(emap: ElevationMap, ground_z_m: float, seed_xy: tuple[float, float],
                   cfg: PlaneLimits) -> F64:
    """The rover's ground per map cell: :func:`ground_plane` bent to follow rolling ground
    (module docstring); the plane itself with ``surface_scale_m`` = 0."""
    ref = ground_plane(emap, ground_z_m, seed_xy, cfg)
    if cfg.surface_scale_m <= 0.0:
        return ref
    z = emap.z
    ok = emap.mapped & np.isfinite(z)
    bend = np.zeros(z.shape, np.float32)
    rows, cols = np.flatnonzero(ok.any(axis=1)), np.flatnonzero(ok.any(axis=0))
    if rows.size == 0:
        return ref
    sigma = cfg.surface_scale_m / emap.grid.cell
    # Only the mapped cells' window and the blur's reach around it (OpenCV's float kernel runs
    # 4 sigma out): past it every input is 0, so the bend there is 0 on the whole grid too.
    pad = int(np.ceil(4.0 * sigma)) + 2
    win = (slice(max(0, int(rows[0]) - pad), int(rows[-1]) + pad + 1),
           slice(max(0, int(cols[0]) - pad), int(cols[-1]) + pad + 1))
    ok_w = ok[win]
    r = np.where(ok_w, z[win] - ref[win], 0.0).astype(np.float32)
    b = np.zeros(r.shape, np.float32)
    for band in (3.0, 2.0, 1.0):
        level = ok_w & (np.abs(r - b) <= band * cfg.plateau_tol_m)
        w = cv2.GaussianBlur(level.astype(np.float32), (0, 0), sigma, borderType=cv2.BORDER_CONSTANT)
        v = cv2.GaussianBlur(np.where(level, r, 0.0).astype(np.float32), (0, 0), sigma,
                             borderType=cv2.BORDER_CONSTANT)
        b = v / np.maximum(w, SURFACE_MIN_WEIGHT)
    bend[win] = b
    return np.asarray(ref + bend, np.float64)
