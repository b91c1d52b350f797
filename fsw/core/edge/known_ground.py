"""Known ground for the geofence: the rover never drives where the flight software has no map
of the ground under its wheels (docs/algorithm.md §2; issue 13 item 3).

Ground is *known* where the elevation map has a measurement (``n >= 1``, docs/algorithm.md §1)
or lies within ``fill_m`` of one (a dilation: stereo drop-outs a few cells wide and the ragged
border of a view, a fraction of a wheel patch), or where the rover's own footprint has stood
(the ground it stands on needs no camera: the body hides it from the mast, yet the wheels are
on it). A swept wheel patch is on
known ground when every map cell whose centre lies inside it is known; a cell off the map grid
is unknown.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import shapely
from numpy.typing import NDArray
from shapely.geometry import Polygon
from shapely.geometry.base import BaseGeometry

from fsw.core.geometry import MapGrid, RoverConfig

Pose3 = tuple[float, float, float]


def rover_footprint(pose: Pose3, rover: RoverConfig, wheel_width_m: float) -> Polygon:
    """The rectangle spanned by the four wheel contact patches at ``pose``."""
    hx = rover.wheelbase_m / 2.0 + rover.wheel_diameter_m / 2.0
    hy = rover.track_m / 2.0 + wheel_width_m / 2.0
    c, s = math.cos(pose[2]), math.sin(pose[2])
    local = np.array([[hx, hy], [hx, -hy], [-hx, -hy], [-hx, hy]])
    xy = np.column_stack([pose[0] + c * local[:, 0] - s * local[:, 1],
                          pose[1] + s * local[:, 0] + c * local[:, 1]])
    return Polygon(xy)


class StoodOn:
    """The footprints the rover has stood on (known ground needing no view): one list, shared by
    every :class:`KnownGround` of a geofence, kept whole by a checkpoint."""

    def __init__(self) -> None:
        self.footprints: list[BaseGeometry] = []
        self.version = 0  # counts the changes of ``footprints``

    def add(self, footprint: BaseGeometry) -> None:
        """A footprint stood on (one already covered by an earlier one adds nothing)."""
        if not any(g.covers(footprint) for g in self.footprints):
            self.footprints.append(footprint)
            self.version += 1

    def replace(self, footprints: list[BaseGeometry] | tuple[BaseGeometry, ...]) -> None:
        """All the ground stood on (a resumed mission's, another task's copy of the mission's)."""
        self.footprints[:] = list(footprints)
        self.version += 1


class KnownGround:
    """The map's known cells plus the ground the rover has stood on (``stood``: shared with
    other views of the same ground; a new, empty one by default)."""

    def __init__(self, fill_m: float, stood: StoodOn | None = None) -> None:
        self.fill_m = fill_m
        self.grid: MapGrid | None = None
        self._mapped: NDArray[np.bool_] | None = None
        self.stood = stood if stood is not None else StoodOn()
        self._map_version = 0  # counts the calls of set_map

    def set_map(self, grid: MapGrid, n: NDArray[np.int32]) -> None:
        """Take the map's measured cells (``n >= 1``), grown by ``fill_m``."""
        mapped = np.asarray(n) >= 1
        r = int(round(self.fill_m / grid.cell))
        if r > 0 and mapped.any():
            k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
            mapped = cv2.dilate(mapped.astype(np.uint8), k).astype(bool)
        self.grid, self._mapped = grid, mapped
        self._map_version += 1

    @property
    def version(self) -> tuple[int, int]:
        """Changes when the known ground may have: a new map or a footprint stood on."""
        return self._map_version, self.stood.version

    def stood_on(self, footprint: BaseGeometry) -> None:
        """Ground the rover's wheels have stood on is known."""
        self.stood.add(footprint)

    def stood_only_near(self, x: float, y: float, radius_m: float) -> bool:
        """Every footprint stood on is centred within ``radius_m`` of ``(x, y)``: the rover has
        not left this place (its start, until a move)."""
        return all(math.hypot(g.centroid.x - x, g.centroid.y - y) <= radius_m for g in self.stood.footprints)

    @property
    def ready(self) -> bool:
        return self._mapped is not None

    def known_xy(self, xy: NDArray[np.float64]) -> NDArray[np.bool_]:
        """(N,) True where points lie on known ground (a mapped cell or a footprint stood on)."""
        pts = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        out = np.zeros(len(pts), bool)
        if self.grid is not None and self._mapped is not None:
            iy, ix, inside = self.grid.cell_index(pts[:, 0], pts[:, 1])
            out[inside] = self._mapped[iy[inside], ix[inside]]
        if self.stood.footprints and len(pts):  # every footprint against every point in one call
            fps = np.empty((len(self.stood.footprints), 1), dtype=object)
            fps[:, 0] = self.stood.footprints
            out |= shapely.contains_xy(fps, pts[None, :, 0], pts[None, :, 1]).any(axis=0)
        return out

    def unknown_cells(self, geom: BaseGeometry) -> int:
        """How many map cells (or cell-sized samples off the map) inside ``geom`` are unknown."""
        return len(self.unknown_points(geom))

    def off_map_cells(self, geom: BaseGeometry) -> int:
        """How many cell-sized samples inside ``geom`` lie off the map grid (never knowable:
        no view can map them)."""
        if self.grid is None or geom.is_empty:
            return 0
        g = self.grid
        x0, y0, x1, y1 = geom.bounds
        if x0 >= g.x0 and y0 >= g.y0 and x1 <= g.x0 + g.nx * g.cell and y1 <= g.y0 + g.ny * g.cell:
            return 0
        pts = self.unknown_points(geom)
        if len(pts) == 0:
            return 0
        iy, ix, inside = g.cell_index(pts[:, 0], pts[:, 1])
        return int((~inside).sum())

    def unknown_points(self, geom: BaseGeometry) -> NDArray[np.float64]:
        """(N, 2) centres of the unknown cells inside ``geom``."""
        none = np.zeros((0, 2))
        if self.grid is None or self._mapped is None or geom.is_empty:
            return none
        g = self.grid
        x0, y0, x1, y1 = geom.bounds
        ix = np.arange(math.floor((x0 - g.x0) / g.cell), math.ceil((x1 - g.x0) / g.cell) + 1)
        iy = np.arange(math.floor((y0 - g.y0) / g.cell), math.ceil((y1 - g.y0) / g.cell) + 1)
        jx, jy = np.meshgrid(ix, iy)
        cx, cy = g.x0 + (jx + 0.5) * g.cell, g.y0 + (jy + 0.5) * g.cell
        inside = shapely.contains_xy(geom, cx, cy)
        if not inside.any():
            return none
        jx, jy, cx, cy = jx[inside], jy[inside], cx[inside], cy[inside]
        on_map = (jx >= 0) & (jx < g.nx) & (jy >= 0) & (jy < g.ny)
        known = np.zeros(jx.shape, bool)
        known[on_map] = self._mapped[jy[on_map], jx[on_map]]
        for fp in self.stood.footprints:
            todo = ~known
            if not todo.any():
                break
            known[todo] = shapely.contains_xy(fp, cx[todo], cy[todo])
        return np.column_stack([cx[~known], cy[~known]])
