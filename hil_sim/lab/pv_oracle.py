"""The brute-force P_V oracle (docs/algorithm.md §3.2): exact, slow, and for tests and benches only.

Every target cell's own ray is traversed exactly (supercover) and ``log Phi`` is summed in
float64, so the flight kernel (``fsw.core.planning.visibility_kernel``, binned rays, float32) can be
checked against it (``safer-hil bench nbv``, tests). It never runs on the rover.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.special import log_ndtr

from fsw.core.planning.visibility import F64, IDX, Terrain


def pv_reference(terrain: Terrain, cam_xyz: tuple[float, float, float], iy: IDX, ix: IDX,
                 chunk: int = 1024) -> F64:
    """Brute-force P_V of cells ``(iy, ix)`` from camera centre ``cam_xyz`` (the test oracle).

    Exact supercover traversal of every target's own ray, exact ``log Phi`` (scipy), float64.
    Costs about 25 us per target cell here; the fast kernel about 2 us (docs/nbv.md).
    """
    g = terrain.grid
    cx, cy, cz = (float(v) for v in cam_xyz)
    c = g.cell
    iy = np.asarray(iy, dtype=np.intp).ravel()
    ix = np.asarray(ix, dtype=np.intp).ravel()
    out = np.empty(iy.size)
    icx, icy = math.floor((cx - g.x0) / c), math.floor((cy - g.y0) / c)
    for s0 in range(0, iy.size, chunk):
        ty, tx = iy[s0:s0 + chunk], ix[s0:s0 + chunk]
        z0 = terrain.elev_m[ty, tx]
        xt, yt = g.x0 + (tx + 0.5) * c, g.y0 + (ty + 0.5) * c
        dx, dy = cx - xt, cy - yt
        tx_cross = _line_params(tx, icx, xt, dx, g.x0, c)
        ty_cross = _line_params(ty, icy, yt, dy, g.y0, c)
        t = np.sort(np.concatenate([tx_cross, ty_cross, np.ones((ty.size, 1))], axis=1), axis=1)
        np.minimum(t, 1.0, out=t)
        t0, t1 = t[:, :-1], t[:, 1:]
        tm = 0.5 * (t0 + t1)
        jx = np.floor((xt[:, None] + tm * dx[:, None] - g.x0) / c).astype(np.intp)
        jy = np.floor((yt[:, None] + tm * dy[:, None] - g.y0) / c).astype(np.intp)
        ok = ((t1 - t0) > 1e-12) & (jx >= 0) & (jx < g.nx) & (jy >= 0) & (jy < g.ny)
        jx, jy = np.clip(jx, 0, g.nx - 1), np.clip(jy, 0, g.ny - 1)
        h = z0[:, None] + tm * (cz - z0[:, None])
        arg = (h - terrain.elev_m[jy, jx]) / terrain.sigma_m[jy, jx]
        lp = np.where(ok, terrain.weight[jy, jx] * log_ndtr(arg), 0.0)
        out[s0:s0 + chunk] = np.exp(lp.sum(axis=1))
    return out


def _line_params(it: IDX, icam: int, p0: NDArray[Any], dp: NDArray[Any], origin: float,
                 c: float) -> F64:
    """Ray parameters ``t`` in (0, 1) where the segment crosses grid lines along one axis."""
    ncross = np.abs(icam - it)
    m = np.arange(max(int(ncross.max(initial=0)), 1))[None, :]
    line = np.where(dp[:, None] > 0, origin + (it[:, None] + 1 + m) * c, origin + (it[:, None] - m) * c)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        t = (line - p0[:, None]) / dp[:, None]
    return np.where(m < ncross[:, None], t, 2.0)
