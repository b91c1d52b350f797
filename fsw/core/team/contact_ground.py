"""The ground the Cliff-bot stands on, known by contact (docs/team.md, "The planner").

No camera sees the ground under a robot's body: the body hides it from the RECON-bot's mast
and from the Cliff-bot's own pair. Yet the Cliff-bot stands there, so that ground holds it.
:func:`fill_under_body` fills the map's unknown cells within the body's radius of where it
stands with the plane fitted (least squares) to the known cells of a ring around the body,
and only when that ring is known well enough and flat enough to trust the plane: at least
``min_ring_cells`` known cells spread over at least three of four quadrants, and an RMS residual
within ``max_rms_m`` (a ring across a lip or a rock is not a plane, and its inside stays unknown).
Known cells are never changed.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from fsw.core.geometry import MapGrid
from fsw.core.team.tether import ZMap

F64 = NDArray[np.float64]


def fill_under_body(z: ZMap, grid: MapGrid, xy: F64, radius_m: float, *,
                    ring_m: float = 0.3, min_ring_cells: int = 12, max_rms_m: float = 0.03) -> tuple[F64, int]:
    """``z`` with the unknown cells under a body standing at ``xy`` filled (module docstring),
    and how many cells were filled (0 when the ring cannot be trusted)."""
    out = np.array(z, dtype=np.float64, copy=True)
    x0, y0 = float(xy[0]), float(xy[1])
    if not (np.isfinite(x0) and np.isfinite(y0) and radius_m > 0 and ring_m > 0):
        return out, 0
    reach = radius_m + ring_m
    iy0, ix0, _ = grid.cell_index(np.array([x0 - reach, x0 + reach]), np.array([y0 - reach, y0 + reach]))
    r0, r1 = max(0, int(min(iy0))), min(grid.ny, int(max(iy0)) + 1)
    c0, c1 = max(0, int(min(ix0))), min(grid.nx, int(max(ix0)) + 1)
    if r0 >= r1 or c0 >= c1:
        return out, 0
    rows, cols = np.mgrid[r0:r1, c0:c1]
    dx = grid.x0 + (cols + 0.5) * grid.cell - x0
    dy = grid.y0 + (rows + 0.5) * grid.cell - y0
    d = np.hypot(dx, dy)
    patch = out[r0:r1, c0:c1]
    known = np.isfinite(patch)
    ring = known & (d > radius_m) & (d <= reach)
    inside = ~known & (d <= radius_m)
    if not inside.any() or int(ring.sum()) < min_ring_cells:
        return out, 0
    quadrants = {(bool(a), bool(b)) for a, b in zip(dx[ring] >= 0, dy[ring] >= 0, strict=True)}
    if len(quadrants) < 3:
        return out, 0
    a = np.column_stack([dx[ring], dy[ring], np.ones(int(ring.sum()))])
    coef, *_ = np.linalg.lstsq(a, patch[ring], rcond=None)
    rms = float(np.sqrt(np.mean((a @ coef - patch[ring]) ** 2)))
    if not np.isfinite(rms) or rms > max_rms_m:
        return out, 0
    patch[inside] = coef[0] * dx[inside] + coef[1] * dy[inside] + coef[2]
    return out, int(inside.sum())
