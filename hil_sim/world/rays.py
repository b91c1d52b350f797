"""Camera rays and heightfield lookups for the ray caster (docs/world.md, "Renderer").

``Heightfield`` (a terrain grid and its height range), ``pixel_rays`` (world directions of
pixel rays for a pinhole camera, ``fsw.core.geometry`` conventions), ``subpixel_rays`` (the
same for several rays per pixel over a box of the image), ``ray_intervals`` (the
part of each ray inside the terrain's slab and box) and ``sample`` (bilinear lookups with
``cv2.remap``, packed for speed).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]

T_NEAR_M = 0.05           # nothing nearer than this is drawn
_MAX_ROWS = 32000         # cv2.remap needs destination sides below 32767
_ROW = 4096


@dataclass(frozen=True, eq=False)
class Heightfield:
    """A terrain grid for ray casting: cell ``(iy, ix)`` has its centre at
    ``(x0 + (ix + 0.5) * cell_m, y0 + (iy + 0.5) * cell_m)``."""

    z: F32
    x0: float
    y0: float
    cell_m: float
    z_min: float
    z_max: float

    @staticmethod
    def from_array(z: F32, x0: float, y0: float, cell_m: float) -> Heightfield:
        z = np.ascontiguousarray(z, dtype=np.float32)
        if max(z.shape) >= 32767:
            raise ValueError(f"heightfield {z.shape} too large for cv2.remap (< 32767 a side)")
        return Heightfield(z, x0, y0, cell_m, float(z.min()), float(z.max()))

    def to_pixel(self, x: F32 | F64, y: F32 | F64) -> tuple[F32, F32]:
        """World ``(x, y)`` to fractional grid coordinates for ``cv2.remap``."""
        return (((x - self.x0) / self.cell_m - 0.5).astype(np.float32),
                ((y - self.y0) / self.cell_m - 0.5).astype(np.float32))


def sample(src: NDArray[np.float32], px: F32, py: F32, *, wrap: bool = False) -> F32:
    """Bilinear lookup of ``src`` (``(h, w)`` or ``(h, w, channels)``) at fractional pixel
    coordinates of any (equal) shape; the result has that shape (plus the channels).

    The coordinates are packed into rows of ``_ROW`` (``cv2.remap`` is fastest on wide
    images and needs sides below 32767)."""
    shape = px.shape
    chans = src.shape[2:]
    n = px.size
    if n == 0:
        return np.zeros(shape + chans, np.float32)
    rows = -(-n // _ROW)
    mx = np.empty(rows * _ROW, np.float32)
    my = np.empty(rows * _ROW, np.float32)
    mx[:n] = px.reshape(-1)
    my[:n] = py.reshape(-1)
    mx[n:] = 0.0
    my[n:] = 0.0
    mx2, my2 = mx.reshape(rows, _ROW), my.reshape(rows, _ROW)
    border = cv2.BORDER_WRAP if wrap else cv2.BORDER_REPLICATE
    out = np.empty((rows, _ROW) + chans, np.float32)
    for r in range(0, rows, _MAX_ROWS):
        out[r:r + _MAX_ROWS] = cv2.remap(src, mx2[r:r + _MAX_ROWS], my2[r:r + _MAX_ROWS],
                                         cv2.INTER_LINEAR, borderMode=border).reshape(
                                             (-1, _ROW) + chans)
    return out.reshape((-1,) + chans)[:n].reshape(shape + chans)


def pixel_rays(R: F64, K: F64, us: F64, vs: F64, dist: F64 | None = None, cache: bool = True) -> F32:
    """World directions ``(len(vs), len(us), 3)`` of pixel rays, scaled so camera ``z`` = 1.

    ``dist`` (OpenCV's ``k1, k2, p1, p2, k3``) makes the pixels those of a distorted
    image: each pixel's ray is its undistorted normalised point (``cv2.undistortPoints``,
    iterated to 1e-10, cached per pixel grid unless ``cache`` is false, as for one-off grids),
    so the image is drawn distorted exactly,
    without resampling. The result is a view of a ``(3, rows, cols)`` array: each component
    ``d[..., k]`` is contiguous, which is how the ray caster reads it."""
    if dist is None:
        f, cx, cy = K[0, 0], K[0, 2], K[1, 2]
        xn: F32 = ((us - cx) / f).astype(np.float32)[None, :]
        yn: F32 = ((vs - cy) / K[1, 1]).astype(np.float32)[:, None]
    else:
        xn, yn = _undistorted_grid(K, dist, us, vs, cache)
    return _world_rays(R, xn, yn)


def subpixel_rays(R: F64, K: F64, dist: F64 | None, box: tuple[int, int, int, int], ss: int) -> F32:
    """:func:`pixel_rays` of ``ss x ss`` rays per pixel over the pixel box ``(u0, v0, u1, v1)``:
    the rays at ``u + (i + 0.5) / ss - 0.5`` for each pixel ``u`` of the box (and alike in
    ``v``), ``((v1 - v0) * ss, (u1 - u0) * ss, 3)``.

    Through a lens the undistorted points are cached in tiles of ``_TILE_PX`` pixels a side
    (per camera and ``ss``): the renderer draws markers and targets this way in every view, in
    boxes that overlap from one view to the next, and undistorting their points afresh each time
    was most of the renderer's time. Each point is undistorted alone, so a tile's points are
    the ones an uncached call gives bit for bit."""
    u0, v0, u1, v1 = box
    if dist is None:
        return pixel_rays(R, K, _subpixels(u0, u1, ss), _subpixels(v0, v1, ss))
    tiles = _tile_cache(K, dist, ss)
    xn = np.empty(((v1 - v0) * ss, (u1 - u0) * ss), np.float32)
    yn = np.empty_like(xn)
    for ty in range(v0 // _TILE_PX, -(-v1 // _TILE_PX)):
        for tx in range(u0 // _TILE_PX, -(-u1 // _TILE_PX)):
            tile = tiles.get((ty, tx))
            if tile is None:
                us = _subpixels(tx * _TILE_PX, (tx + 1) * _TILE_PX, ss)
                vs = _subpixels(ty * _TILE_PX, (ty + 1) * _TILE_PX, ss)
                tile = tiles[(ty, tx)] = _undistorted_grid(K, dist, us, vs, cache=False)
            # the part of the tile inside the box, in pixels, then in rays
            a_u, b_u = max(u0, tx * _TILE_PX), min(u1, (tx + 1) * _TILE_PX)
            a_v, b_v = max(v0, ty * _TILE_PX), min(v1, (ty + 1) * _TILE_PX)
            dst = (slice((a_v - v0) * ss, (b_v - v0) * ss), slice((a_u - u0) * ss, (b_u - u0) * ss))
            src = (slice((a_v - ty * _TILE_PX) * ss, (b_v - ty * _TILE_PX) * ss),
                   slice((a_u - tx * _TILE_PX) * ss, (b_u - tx * _TILE_PX) * ss))
            xn[dst] = tile[0][src]
            yn[dst] = tile[1][src]
    return _world_rays(R, xn, yn)


def _subpixels(a: int, b: int, ss: int) -> F64:
    """The ``ss`` ray coordinates per pixel of pixels ``a .. b - 1``: ``p + (i + 0.5) / ss - 0.5``."""
    sub = (np.arange(ss) + 0.5) / ss - 0.5
    return np.asarray((np.arange(a, b)[:, None] + sub[None, :]).reshape(-1), np.float64)


def _world_rays(R: F64, xn: F32, yn: F32) -> F32:
    """World directions of the normalised points ``xn, yn`` (broadcast to ``(rows, cols)``)."""
    r = R.astype(np.float32)
    out = np.empty((3, yn.shape[0], xn.shape[1]), np.float32)
    for k in range(3):
        np.multiply(xn, r[k, 0], out=out[k])
        out[k] += yn * r[k, 1]
        out[k] += r[k, 2]
    return np.moveaxis(out, 0, -1)


_GRID_CACHE: dict[bytes, tuple[F32, F32]] = {}
_GRID_CACHE_SIZE = 12
_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-10)
_TILE_PX = 64
_TILE_CACHE: dict[bytes, dict[tuple[int, int], tuple[F32, F32]]] = {}
_TILE_CACHE_SIZE = 4  # cameras x ray counts; a whole image's tiles at 2560 x 1920 rays are 39 MB


def _tile_cache(K: F64, dist: F64, ss: int) -> dict[tuple[int, int], tuple[F32, F32]]:
    """The undistorted tiles of one camera at ``ss`` rays per pixel side (filled as used)."""
    key = b"".join(np.ascontiguousarray(a, np.float64).tobytes() for a in (K, dist, np.array([ss])))
    tiles = _TILE_CACHE.get(key)
    if tiles is None:
        if len(_TILE_CACHE) >= _TILE_CACHE_SIZE:
            _TILE_CACHE.pop(next(iter(_TILE_CACHE)))
        tiles = _TILE_CACHE[key] = {}
    return tiles


def _undistorted_grid(K: F64, dist: F64, us: F64, vs: F64, cache: bool) -> tuple[F32, F32]:
    """Normalised undistorted coordinates ``(rows, cols)`` of the pixel grid ``us x vs``."""
    key = b"".join(np.ascontiguousarray(a, np.float64).tobytes() for a in (K, dist, us, vs))
    hit = _GRID_CACHE.get(key) if cache else None
    if hit is not None:
        return hit
    uu, vv = np.meshgrid(np.asarray(us, np.float64), np.asarray(vs, np.float64))
    pts = np.stack([uu.ravel(), vv.ravel()], axis=-1).reshape(-1, 1, 2)
    und = cv2.undistortPoints(pts, K, np.asarray(dist, np.float64), criteria=_UNDISTORT_CRITERIA)
    und = und.reshape(uu.shape + (2,))
    grid = (np.ascontiguousarray(und[..., 0], np.float32), np.ascontiguousarray(und[..., 1], np.float32))
    if cache:
        if len(_GRID_CACHE) >= _GRID_CACHE_SIZE:
            _GRID_CACHE.pop(next(iter(_GRID_CACHE)))
        _GRID_CACHE[key] = grid
    return grid


def ray_intervals(hf: Heightfield, c: F64, d: F32) -> tuple[F32, F32]:
    """``[t_lo, t_hi]`` of each ray inside the terrain's slab and box (empty if lo >= hi)."""
    ny, nx = hf.z.shape
    lo = np.full(d.shape[:-1], T_NEAR_M, np.float32)
    hi = np.full(d.shape[:-1], np.inf, np.float32)
    bounds = ((hf.x0 + 0.5 * hf.cell_m, hf.x0 + (nx - 0.5) * hf.cell_m),
              (hf.y0 + 0.5 * hf.cell_m, hf.y0 + (ny - 0.5) * hf.cell_m),
              (hf.z_min - 1e-3, hf.z_max + 1e-3))
    with np.errstate(divide="ignore", invalid="ignore"):
        for axis, (b0, b1) in enumerate(bounds):
            da = d[..., axis]
            t0 = (b0 - c[axis]) / da
            t1 = (b1 - c[axis]) / da
            parallel = np.abs(da) < 1e-9
            inside = (b0 <= c[axis]) & (c[axis] <= b1)
            lo = np.where(parallel, np.where(inside, lo, np.inf), np.maximum(lo, np.minimum(t0, t1)))
            hi = np.where(parallel, hi, np.minimum(hi, np.maximum(t0, t1)))
    return lo.astype(np.float32), hi.astype(np.float32)
