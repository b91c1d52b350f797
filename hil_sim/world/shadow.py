"""Cast shadows on a heightfield from a distant sun (the renderer's baked lighting).

A cell is in shadow when the terrain between it and the sun rises above the ray toward the
sun. Along one horizontal line in the sun's azimuth, with ``s`` the distance toward the sun,
the ray from the cell at ``s0`` has height ``h(s0) + (s - s0) tan(el)``; the cell is shadowed
iff ``max_{s > s0} (h(s) - s tan(el)) > h(s0) - s0 tan(el)``. That is one suffix maximum per
line (a "horizon" sweep, exact for the sampled terrain and O(cells)):

1. resample the heightfield onto a grid rotated so that the sun's azimuth runs along its
   columns (bilinear, ``cv2.remap``); samples not wholly inside the world are neither lit
   nor occluders (nothing beyond the world's edge casts a shadow);
2. per row, ``np.maximum.accumulate`` of ``h - s tan(el)`` from the sun's side;
3. sample the shadow back onto the original cells (bilinear on the 0/1 mask, so a shadow's
   border is softened over about a cell, like a short penumbra).

Occluders lower than ``tolerance_m`` above the ray do not cast (resampling noise on rough
ground would otherwise speckle the lit slopes). Method and figures: docs/world.md, "Sun and
shadows".
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from numpy.typing import NDArray

F32 = NDArray[np.float32]

_FAR_BELOW = np.float32(-1e6)  # terrain outside the world: never an occluder


def cast_shadow(height: F32, cell_m: float, sun_azimuth_deg: float, sun_elevation_deg: float,
                tolerance_m: float | None = None) -> F32:
    """Lit fraction per cell (1 lit, 0 in shadow, in between on a shadow's border).

    ``height`` is indexed ``[iy, ix]`` (rows along world ``y``, columns along ``x``), the
    azimuth is measured from ``+x`` toward ``+y`` and the elevation above the horizon.
    ``tolerance_m`` defaults to one cell's rise of the sun ray, at least 5 mm.
    """
    h = np.asarray(height, np.float32)
    if h.ndim != 2 or not np.isfinite(h).all():
        raise ValueError("height must be a finite 2-D array")
    if not (cell_m > 0 and math.isfinite(cell_m)):
        raise ValueError(f"cell_m must be > 0, got {cell_m}")
    if not 0.0 < sun_elevation_deg <= 90.0:
        raise ValueError(f"sun elevation must be in (0, 90] deg, got {sun_elevation_deg}")
    if sun_elevation_deg >= 89.9:
        return np.ones_like(h)
    tan_el = math.tan(math.radians(sun_elevation_deg))
    tol = max(0.005, cell_m * tan_el) if tolerance_m is None else float(tolerance_m)
    ny, nx = h.shape
    az = math.radians(sun_azimuth_deg)
    ex = np.array([math.cos(az), math.sin(az)])  # toward the sun, in (ix, iy) units
    ey = np.array([-ex[1], ex[0]])
    side = int(math.ceil(math.hypot(nx, ny))) + 2
    centre = np.array([(nx - 1) / 2.0, (ny - 1) / 2.0])
    half = (side - 1) / 2.0
    # rotated grid: column j runs toward the sun, row i across it
    j = np.arange(side, dtype=np.float64) - half
    i = np.arange(side, dtype=np.float64) - half
    map_x = (centre[0] + j[None, :] * ex[0] + i[:, None] * ey[0]).astype(np.float32)
    map_y = (centre[1] + j[None, :] * ex[1] + i[:, None] * ey[1]).astype(np.float32)
    rot = cv2.remap(h, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                    borderValue=0.0)
    inside = cv2.remap(np.ones_like(h), map_x, map_y, cv2.INTER_LINEAR,
                       borderMode=cv2.BORDER_CONSTANT, borderValue=0.0) > 0.999
    s_m = (np.arange(side, dtype=np.float32) * np.float32(cell_m))[None, :]
    u = np.where(inside, rot - s_m * np.float32(tan_el), _FAR_BELOW)
    # the highest occluder strictly toward the sun (columns j+1 ..)
    ahead = np.maximum.accumulate(u[:, ::-1], axis=1)[:, ::-1]
    ahead = np.concatenate([ahead[:, 1:], np.full((side, 1), _FAR_BELOW, np.float32)], axis=1)
    shadow = (inside & (ahead > u + np.float32(tol))).astype(np.float32)
    # back to the world grid: the rotated coordinates of every cell
    ix, iy = np.meshgrid(np.arange(nx, dtype=np.float64), np.arange(ny, dtype=np.float64))
    dx, dy = ix - centre[0], iy - centre[1]
    back_x = (dx * ex[0] + dy * ex[1] + half).astype(np.float32)
    back_y = (dx * ey[0] + dy * ey[1] + half).astype(np.float32)
    shade = cv2.remap(shadow, back_x, back_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                      borderValue=0.0)
    return np.asarray(1.0 - np.clip(shade, 0.0, 1.0), np.float32)
