"""Stamping rocks into a heightfield, vectorised by size class.

A rock is a rounded, slightly elongated dome (a superellipse footprint with an elliptic
vertical profile) of diameter ``D`` and height ``H`` above the ground under its centre,
partly buried so it blends into sloping ground. Rocks combine with the terrain and with
each other by taking the maximum, so later rocks can sit on earlier ones (rock piles are
stamped in layers). Used by the Viking model (``mars.py``), the lab rock piles and the
cliff's rock jumble; see docs/world.md, "Scenarios".
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]

_MAX_BATCH_ELEMS = 3_000_000  # stencil samples per vectorised batch (memory bound)


def stamp_rocks(
    height: F32,
    x0: float,
    y0: float,
    cell_m: float,
    x_m: F64,
    y_m: F64,
    d_m: F64,
    h_m: F64,
    rng: np.random.Generator,
    *,
    rock_id: NDArray[np.int32] | None = None,
    first_id: int = 0,
) -> None:
    """Stamp rocks centred at ``(x_m, y_m)`` (world metres) into ``height`` in place.

    ``height`` is the ``(ny, nx)`` grid whose cell ``(iy, ix)`` has its centre at
    ``(x0 + (ix + 0.5) * cell_m, y0 + (iy + 0.5) * cell_m)``. Each rock's base is the current
    height under its centre, so rocks stack on whatever was stamped before. If ``rock_id``
    is given, cells where a rock ends up on top receive ``first_id + index`` of that rock.
    Shape parameters (elongation, orientation, blockiness, burial) come from ``rng``.
    """
    n = len(x_m)
    if n == 0:
        return
    ny, nx = height.shape
    x_m, y_m = np.asarray(x_m, float), np.asarray(y_m, float)
    d_m, h_m = np.asarray(d_m, float), np.asarray(h_m, float)
    elong = rng.uniform(0.75, 1.0, n)           # minor / major semi-axis
    angle = rng.uniform(0.0, np.pi, n)
    power = rng.uniform(2.0, 3.2, n)            # superellipse exponent: 2 round, 3 blocky
    bury = rng.uniform(0.05, 0.2, n) * h_m      # part of the rock below the local ground
    cx = (x_m - x0) / cell_m - 0.5              # fractional cell coordinates of centres
    cy = (y_m - y0) / cell_m - 0.5
    icx = np.clip(np.round(cx).astype(np.intp), 0, nx - 1)
    icy = np.clip(np.round(cy).astype(np.intp), 0, ny - 1)
    inside = (cx >= -0.5) & (cx <= nx - 0.5) & (cy >= -0.5) & (cy <= ny - 0.5)
    base = np.where(inside, height[icy, icx], np.nan)
    # Rocks whose centre is off the grid take the nearest edge height as base.
    base = np.where(np.isnan(base), height[icy, icx], base) - bury
    radius_cells = 0.5 * d_m / cell_m
    need = np.ceil(radius_cells + 1.0)
    size_class = (2 ** np.ceil(np.log2(np.maximum(need, 1.0)))).astype(np.intp)
    flat = height.reshape(-1)
    for r in np.unique(size_class):
        members = np.nonzero(size_class == r)[0]
        off = np.arange(-r, r + 1)
        per = off.size * off.size
        step = max(1, _MAX_BATCH_ELEMS // per)
        for s in range(0, members.size, step):
            idx = members[s : s + step]
            _stamp_batch(flat, (ny, nx), off, idx, cx, cy, icx, icy, radius_cells, elong,
                         angle, power, base, h_m + bury, rock_id, first_id)


def _stamp_batch(flat, shape, off, idx, cx, cy, icx, icy, radius, elong, angle, power, base,
                 amp, rock_id, first_id) -> None:  # type: ignore[no-untyped-def]
    ny, nx = shape
    gy = icy[idx, None, None] + off[None, :, None]
    gx = icx[idx, None, None] + off[None, None, :]
    dx = gx - cx[idx, None, None]
    dy = gy - cy[idx, None, None]
    ca, sa = np.cos(angle[idx])[:, None, None], np.sin(angle[idx])[:, None, None]
    a = radius[idx][:, None, None]
    b = a * elong[idx][:, None, None]
    u = np.abs(ca * dx + sa * dy) / a
    v = np.abs(-sa * dx + ca * dy) / b
    p = power[idx][:, None, None]
    rho2 = (u**p + v**p) ** (2.0 / p)
    z = base[idx][:, None, None] + amp[idx][:, None, None] * np.sqrt(np.clip(1.0 - rho2, 0.0, None))
    ok = (rho2 < 1.0) & (gx >= 0) & (gx < nx) & (gy >= 0) & (gy < ny)
    lin = (gy * nx + gx)[ok]
    zz = z[ok].astype(np.float32)
    np.maximum.at(flat, lin, zz)
    if rock_id is not None:
        ids = np.broadcast_to((first_id + idx)[:, None, None], ok.shape)[ok].astype(np.int32)
        won = flat[lin] <= zz
        rock_id.reshape(-1)[lin[won]] = ids[won]
