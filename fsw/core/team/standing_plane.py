"""The plane the Cliff-bot stands on: a plane fitted to the ground under it and round it (docs/algorithm.md §8).

The statics of one place (:mod:`fsw.core.team.tether`) need the ground's upward normal where
the Cliff-bot stands (it sets the normal force's direction and, with the attachment height,
the tethers' end): the plane fitted by least squares to the bilinear heights at the place and
at eight points on a circle round it (the footprint), so the normal and the attachment point
move continuously with the Cliff-bot. :func:`plane_normals` fits a batch of places in one
LAPACK call with the same values as :func:`plane_normal` one at a time.
"""

from __future__ import annotations

import functools

import numpy as np

from fsw.core.geometry import MapGrid
from fsw.core.team.tether_batch import F64, ZMap, heights_at, vector_norm

# the gufunc np.linalg.lstsq calls (numpy >= 2.0), for fitting many planes in one call (plane_normals)
_GELSD: np.ufunc | None = getattr(np.linalg._umath_linalg, "lstsq", None)  # type: ignore[attr-defined]


_RING = np.arange(8) * (np.pi / 4)
_RING_COS, _RING_SIN = np.cos(_RING), np.sin(_RING)


def ring(radius_m: float, grid: MapGrid) -> tuple[F64, F64, F64]:
    """The footprint's centre and eight points on the circle of ``radius_m`` (at least a cell),
    and the plane fit's design matrix over them (columns x, y, 1): read-only, made once per
    radius (every tether state fits a plane over the same ring)."""
    return _ring_of(max(radius_m, grid.cell))


@functools.lru_cache(maxsize=16)
def _ring_of(r: float) -> tuple[F64, F64, F64]:
    px = np.empty(9)
    py = np.empty(9)
    px[0], px[1:] = 0.0, r * _RING_COS
    py[0], py[1:] = 0.0, r * _RING_SIN
    design = np.column_stack([px, py, np.ones_like(px)])
    for a in (px, py, design):
        a.flags.writeable = False
    return px, py, design


def plane_normal(design: F64, h: F64) -> F64 | None:
    """The upward unit normal of the plane fitted to the heights ``h`` at the ring's points
    (``design``, :func:`ring`; NaN: left out); None when the centre or more than half of the
    circle is unknown. Where every height is known (most places) the whole design matrix is the
    fit's, with no selection."""
    ok = np.isfinite(h)
    if not ok[0]:
        return None
    if ok.all():
        a, hk = design, h
    elif ok.sum() < 5:
        return None
    else:
        a, hk = design[ok], h[ok]
    (gx, gy, _), *_ = np.linalg.lstsq(a, hk, rcond=None)
    n = np.array([-gx, -gy, 1.0])
    return n / vector_norm(n)


def plane_normals(design: F64, h: F64) -> list[F64 | None]:
    """:func:`plane_normal` of each row of ``h`` (N, 9), the same values: the rows whose every
    height is known (most places) fitted in one call of the gufunc ``np.linalg.lstsq`` wraps
    (LAPACK's ``gelsd`` on each matrix, with lstsq's default ``rcond``), the others one at a
    time. A batch of tether states fits a plane per place, and lstsq's checks and wrapping cost
    several times its solve for a 9 x 3 fit."""
    gelsd = _GELSD
    full = np.isfinite(h).all(axis=1) if gelsd is not None else np.zeros(len(h), bool)
    out: list[F64 | None] = [None] * len(h)
    if gelsd is not None and full.any():
        rcond = np.finfo(np.float64).eps * max(design.shape)
        with np.errstate(over="ignore", divide="ignore", under="ignore"):
            fits: F64 = gelsd(design, h[full][:, :, None], rcond, signature="ddd->ddid")[0][:, :, 0]
        for k, (gx, gy, _) in zip(np.flatnonzero(full), fits, strict=True):
            n = np.array([-gx, -gy, 1.0])
            out[int(k)] = n / vector_norm(n)
    for k in np.flatnonzero(~full):
        out[int(k)] = plane_normal(design, h[k])
    return out


def surface_normal(z: ZMap, grid: MapGrid, xy: F64, radius_m: float) -> F64 | None:
    """Unit upward normal of the plane fitted to the ground at ``xy`` and at eight points on
    the circle of ``radius_m`` around it (bilinear heights, :func:`~fsw.core.team.tether.height_at`, so the normal
    and the attachment point move continuously with the Cliff-bot); points on unknown ground
    or off the map are left out; None when the centre or more than half of the circle is."""
    px, py, design = ring(radius_m, grid)
    return plane_normal(design, heights_at(z, grid, float(xy[0]) + px, float(xy[1]) + py))
