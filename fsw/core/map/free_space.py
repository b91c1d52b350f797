"""Free space along stereo rays: air under a mapped surface is an overhang (docs/algorithm.md §8.1).

A stereo point ``p`` seen from the camera centre ``c`` proves that the segment from ``c`` to
``p`` is air, up to the point's own error: the segment is cut ``stop`` short of ``p`` (a few
sigma of the point and one cell). In a 2.5D grid whose "up" is ``w`` (the face map's normal), a
cell holds one surface height ``z``: ground just below it, air above. A ray that crosses the
cell's column at ``w_r`` well below ``z`` shows air under that ground, so along the column the
surface is crossed at least three times (ground far inside, air at ``w_r``, ground under ``z``,
air above): a second surface, an overhang, even when no view ever saw the inner surface. This
is the multi-level surface map's test (Triebel, Pfaff and Burgard 2006: a measurement passing
below a mapped surface patch proves a second, lower patch).

"Well below" is ``z - w_r > gap + k sqrt(var_z + var_r)``: the overhang gap (the truth's
definition of two surfaces) plus ``k`` sigma of the cell's height and of the ray's position
along ``w`` (the pose error turns every sight line; the point's ``w`` variance bounds it).

:func:`air_under` samples each ray every ``step`` inside the grid's box (``u``, ``v`` on the
grid, ``w`` in the slab) and returns, per cell, the number of distinct rays that passed below
its surface and the lowest ``w`` they reached (the inner surface lies below it).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from fsw.core.geometry import MapGrid

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]


def _box_interval(eye: F64, d: F64, lo: F64, hi: F64) -> tuple[F64, F64]:
    """``(t0, t1)`` per ray ``eye + t d`` inside the box ``[lo, hi)`` (empty where ``t1 <= t0``)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        dd = np.where(d == 0.0, 1e-300, d)
        ta = (lo - eye) / dd
        tb = (hi - eye) / dd
    t0 = np.max(np.minimum(ta, tb), axis=1)
    t1 = np.min(np.maximum(ta, tb), axis=1)
    return t0, t1


def air_under(grid: MapGrid, z: F64, var: F64, eye: F64, q: F64, var_r: F64, stop: F64,
              w_range: tuple[float, float], gap_m: float, k_sigma: float, step_m: float,
              chunk_samples: int = 1_000_000) -> tuple[I64, F64]:
    """Rays from ``eye`` (3,) to the points ``q`` (N, 3), all in the grid's frame (``u``, ``v``
    on ``grid``, ``w`` up), each cut ``stop`` (N,) metres short of its point and sampled every
    ``step_m`` inside the grid's box with ``w`` in ``w_range``. Returns ``(rays, lowest)`` per
    cell (flat): how many distinct rays crossed the cell's column below its surface by more than
    ``gap_m + k_sigma sqrt(var + var_r)`` (``z``, ``var``: the grid's heights and variances,
    NaN / inf where unmapped; ``var_r`` (N,) the rays' variance along ``w``), and the lowest
    ``w`` any of them reached there (inf: none)."""
    size = grid.nx * grid.ny
    rays = np.zeros(size, np.int64)
    lowest = np.full(size, np.inf)
    eye = np.asarray(eye, float).reshape(3)
    q = np.asarray(q, float).reshape(-1, 3)
    d = q - eye
    length = np.linalg.norm(d, axis=1)
    ok = np.isfinite(length) & np.isfinite(var_r) & (length > stop) & np.isfinite(stop)
    if not ok.any():
        return rays, lowest
    d, length, var_r, stop = d[ok], length[ok], np.asarray(var_r, float)[ok], np.asarray(stop, float)[ok]
    lo = np.array([grid.x0, grid.y0, w_range[0]])
    hi = np.array([grid.x0 + grid.nx * grid.cell, grid.y0 + grid.ny * grid.cell, w_range[1]])
    t0, t1 = _box_interval(eye, d, lo, hi)
    t0 = np.maximum(t0, 0.0)
    t1 = np.minimum(t1, 1.0 - stop / length)
    n = np.where(t1 > t0, np.floor((t1 - t0) * length / step_m), 0.0).astype(np.int64)
    live = np.flatnonzero(n > 0)
    if live.size == 0:
        return rays, lowest
    zf, vf = z.reshape(-1), var.reshape(-1)
    ends = np.cumsum(n[live])
    start = 0
    while start < live.size:  # chunks of rays holding about chunk_samples samples
        before = 0 if start == 0 else int(ends[start - 1])
        stop_i = max(start + 1, int(np.searchsorted(ends, before + chunk_samples, side="right")))
        sel = live[start:stop_i]
        k = n[sel]
        ray = np.repeat(np.arange(sel.size), k)
        first = np.cumsum(k) - k
        step = np.arange(int(k.sum())) - np.repeat(first, k)
        r = sel[ray]
        t = t0[r] + (step + 0.5) * step_m / length[r]
        p = eye + t[:, None] * d[r]
        iu = np.floor((p[:, 0] - grid.x0) / grid.cell).astype(np.intp)
        iv = np.floor((p[:, 1] - grid.y0) / grid.cell).astype(np.intp)
        inside = (iu >= 0) & (iu < grid.nx) & (iv >= 0) & (iv < grid.ny)
        cell = np.where(inside, iv * grid.nx + iu, 0)
        zc, vc = zf[cell], vf[cell]
        with np.errstate(invalid="ignore"):
            below = inside & np.isfinite(zc) & (zc - p[:, 2] > gap_m + k_sigma * np.sqrt(vc + var_r[r]))
        if below.any():
            pair = np.unique(r[below].astype(np.int64) * size + cell[below])
            rays += np.bincount(pair % size, minlength=size)
            np.minimum.at(lowest, cell[below], p[below, 2])
        start = stop_i
    return rays, lowest
