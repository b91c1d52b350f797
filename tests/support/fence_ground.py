"""The mission's ground (``mission.ground``) for unit tests of a task whose wheel moves the
geofence checks on it (the fixer's turns in place): a map measured everywhere on the grid but
where ``unmapped`` says, no drop cell, no edge fit, nothing stood on."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from fsw.core.geometry import MapGrid
from fsw.core.map.elevation_map import ElevationMap
from fsw.settings import FswConfig
from fsw.tasks.messages import MapUpdate, MissionGroundState


def mission_ground(cfg: FswConfig,
                   unmapped: Callable[[NDArray[np.float64], NDArray[np.float64]], NDArray[np.bool_]] | None = None
                   ) -> MissionGroundState:
    """Flat ground at 0 m mapped once on every cell whose centre ``(x, y)`` is not ``unmapped``."""
    grid = MapGrid.from_config(cfg.map)
    emap = ElevationMap(grid)
    ix, iy = np.meshgrid(np.arange(grid.nx), np.arange(grid.ny))
    x, y = grid.x0 + (ix + 0.5) * grid.cell, grid.y0 + (iy + 0.5) * grid.cell
    seen = np.ones(grid.shape, bool) if unmapped is None else ~unmapped(x, y)
    emap.n[seen], emap.z[seen], emap.var[seen] = 1, 0.0, 1e-4
    up = MapUpdate(1, 0.0, int(seen.sum()), 0, 0, 0, 0.0, emap, drop=np.zeros(grid.shape, bool))
    return MissionGroundState(up, None, ())
