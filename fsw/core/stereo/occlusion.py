"""Occluding lips of a view and the points too close to them to place (docs/algorithm.md §1.2, §4).

A camera on the plateau never sees the ground right behind a drop (a cliff's face, the lee of
a rock): in the image the lip's pixels are followed, one or a few rows higher, by ground much
farther away, with nothing between. Where the view's points are uncertain horizontally (the
pose term of §1.2 after a drive that registration could not correct, and the stereo range
error), a point near the lip may belong on either side of it; placed past the lip it gives
the occluded cells the plateau's height, which no later view from the plateau can correct
(they cannot see those cells either). The map's slope term does not see it: the view has no
points behind the lip, so its own gradient there is flat.

So, per view:

1. **Lips** (:func:`lip_pixels`, image space): a valid pixel whose disparity exceeds by more
   than ``jump_px`` the smallest valid disparity within ``rows`` rows above it (farther
   ground, with at most a few unmatched rows between: the width of the matching windows at a
   depth jump). A textureless patch spans many rows and a continuous surface changes little
   over a few rows, so neither is a lip. The lip's near point and the far point behind it
   are triangulated (``StereoMatcher.triangulate``).
2. **Drops** (:class:`LipGuard`, world frame, after the pose): a lip counts when its near
   point lies more than ``min_drop_m`` above the far one.
3. **Guard**: a point of the view is not merged when its horizontal distance to the nearest
   lip of the same view is below ``k`` times its horizontal 1-sigma (the larger eigenvalue of
   the ``xy`` block of its world covariance, stereo plus pose). A view with an accurate pose
   loses the points within a few cm of its lips; a view with a large pose uncertainty gives no
   heights near a drop it cannot place (docs/perception.md, "Occluding lips"). The lips the map
   already knows (those earlier views found, ``fsw.core.map.known_lips``) guard the view's
   points past them as well.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from fsw.core.geometry import CameraPose, MapGrid
from fsw.core.map.known_lips import PastLips, horizontal_variance, largest_variance, on_sight_line

F64 = NDArray[np.float64]
I64 = NDArray[np.intp]


def lip_pixels(disp: F64, jump_px: float, rows: int) -> tuple[I64, I64, I64]:
    """Occluding lips of a disparity image (NaN = no match): rows and columns of the lip
    pixels and the row of the farthest valid pixel within ``rows`` rows above each (the
    ground behind the lip)."""
    ok = np.isfinite(disp)
    d = np.where(ok, disp, np.inf)
    far = np.full(d.shape, np.inf)  # the smallest disparity within ``rows`` rows above
    reach = range(1, min(rows, d.shape[0] - 1) + 1)
    for k in reach:
        np.minimum(far[k:], d[:-k], out=far[k:])
    with np.errstate(invalid="ignore"):
        v, u = np.nonzero(ok & (d - far > jump_px))  # inf - inf is NaN: no valid pixel above
    cand = np.stack([np.where(v >= k, d[np.maximum(v - k, 0), u], np.inf) for k in reach]) if v.size else None
    return v, u, v - 1 - (np.argmin(cand, axis=0) if cand is not None else v)  # the nearest such row


class LipGuard:
    """The lips of one view in the map grid; which of the view's points are clear of them."""

    def __init__(self, grid: MapGrid, near_w: F64, far_w: F64, min_drop_m: float) -> None:
        self.grid = grid
        drop = near_w[:, 2] - far_w[:, 2]
        counted = np.isfinite(drop) & (drop > min_drop_m)
        near, far = near_w[counted], far_w[counted]
        ix = np.floor((near[:, 0] - grid.x0) / grid.cell).astype(np.intp)
        iy = np.floor((near[:, 1] - grid.y0) / grid.cell).astype(np.intp)
        inside = (ix >= 0) & (ix < grid.nx) & (iy >= 0) & (iy < grid.ny)
        self.lips = int(np.count_nonzero(inside))
        # the counted lips in the grid: their near point and the horizontal way to the far side
        # (the drop side), what the map keeps of them (fsw.core.map.known_lips)
        self.near = near[inside]
        way = far[inside, :2] - self.near[:, :2]
        self.toward = way / np.maximum(np.linalg.norm(way, axis=1, keepdims=True), 1e-12)
        self._nearest: F64 | None = None  # per cell, the nearest lip's near point and way to its drop
        if self.lips:
            ix, iy, near = ix[inside], iy[inside], near[inside]
            lip = np.full(grid.shape + (5,), np.nan)
            lip[iy, ix] = np.column_stack([near, self.toward])  # one lip per cell
            idx = ndimage.distance_transform_edt(np.isnan(lip[..., 0]), return_distances=False,
                                                 return_indices=True)
            self._nearest = lip[idx[0], idx[1]]

    @classmethod
    def of_view(cls, grid: MapGrid, pose: CameraPose, near_c: F64, far_c: F64, min_drop_m: float) -> LipGuard:
        """The guard of a view from its lips in the camera frame (``StereoPoints.lip_near_c``,
        ``lip_far_c``) and its camera pose (after registration)."""
        return cls(grid, pose.camera_to_world(near_c), pose.camera_to_world(far_c), min_drop_m)

    def part(self, xyz_w: F64, cov_stereo: F64, cov_common: F64 | None, k_sigma: float,
             known: PastLips | None = None, eye: F64 | None = None) -> tuple[F64, F64, F64 | None]:
        """One part of the view for the merge, ``(xyz, cov, cov_common)``, without the points
        too near one of its lips given the view's common covariance (None: an exact pose,
        nothing held), nor those past a lip the map ``known`` already (``fsw.core.map.known_lips``);
        with the camera centre ``eye``, only lips on a point's sight line withhold it."""
        if cov_common is None:
            return xyz_w, cov_stereo, None
        keep = self.clear(xyz_w, cov_common, k_sigma, eye)
        if known is not None:
            keep &= known.clear(xyz_w, cov_common, k_sigma, eye)
        return xyz_w[keep], (cov_stereo + cov_common)[keep], cov_common[keep]

    def clear(self, xyz_w: F64, cov_w: F64, k_sigma: float, eye: F64 | None = None) -> NDArray[np.bool_]:
        """Points whose horizontal distance to the nearest lip exceeds ``k_sigma`` times
        their horizontal 1-sigma, or, with the camera centre ``eye``, that the lip does not hide
        from it within ``k_sigma`` times their largest 1-sigma in any direction
        (``fsw.core.map.known_lips.on_sight_line``) (points off the grid: True, the merge drops
        them anyway)."""
        n = xyz_w.shape[0]
        if self._nearest is None or k_sigma <= 0.0 or n == 0:
            return np.ones(n, bool)
        g = self.grid
        with np.errstate(invalid="ignore"):
            ix = np.floor((xyz_w[:, 0] - g.x0) / g.cell)
            iy = np.floor((xyz_w[:, 1] - g.y0) / g.cell)
            inside = (ix >= 0) & (ix < g.nx) & (iy >= 0) & (iy < g.ny)
        out = np.ones(n, bool)
        ii, jj = iy[inside].astype(np.intp), ix[inside].astype(np.intp)
        p, nearest = xyz_w[inside], self._nearest[ii, jj]
        lip, toward = nearest[:, :3], nearest[:, 3:]
        dx, dy = p[:, 0] - lip[:, 0], p[:, 1] - lip[:, 1]
        cov_in = cov_w[inside]
        held = dx * dx + dy * dy <= k_sigma * k_sigma * horizontal_variance(cov_in)
        if eye is not None and held.any():  # the point's noise in any direction
            reach2 = k_sigma * k_sigma * largest_variance(cov_in[held])
            held[held] = on_sight_line(eye, p[held], lip[held], toward[held], reach2)
        out[inside] = ~held
        return out
