"""The world truth the HIL bench measures the flight software against.

A :class:`World` is a fine heightfield (cells of 1 cm or less) with a natural albedo texture,
the true cliff edge, the rover's start pose and the Cliff-bot with its ArUco markers. The
stereo renderer (``hil_sim/render.py``) draws it; the map engineers compare their elevation
map with :meth:`World.truth_on_grid` (docs/algorithm.md §1) and the interest-function experiment
with :meth:`World.textureless_on_grid` (docs/algorithm.md §3.4). Scenarios are built by
``hil_sim.world.load_scenario``; docs/world.md describes them.

Conventions (``fsw.core.geometry``): world metres, ``z`` up; heightfield cell ``(iy, ix)``
covers ``x0 + ix * cell_m .. x0 + (ix + 1) * cell_m`` (likewise ``y``) and its value is the
height at the cell centre; :meth:`World.height_at` interpolates bilinearly between centres.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from fsw.core.geometry import MapGrid, MapGridConfig, MastConfig, point_mast
from hil_sim.team.team_truth import TeamTruth
from hil_sim.world.cliffbot import CliffbotTruth, Quad

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]
Pose2 = tuple[float, float, float]  # (x, y, yaw): a frame's origin and heading in the world
ORIGIN: Pose2 = (0.0, 0.0, 0.0)


@dataclass(frozen=True, eq=False)
class World:
    """A scenario's truth. Arrays are read-only (worlds are cached and shared).

    ``safe_side_sign``: +1 when the plateau (the rover's safe ground) lies to the LEFT of the
    edge polyline ``edge_xy`` walked in point order (counter-clockwise side, i.e. the sign of
    the z component of ``direction x (point - edge)``), -1 when it lies to the right. All
    built-in scenarios run the edge along ``+x`` with the plateau at larger ``y``: ``+1``.
    """

    name: str
    seed: int
    x0: float
    y0: float
    cell_m: float
    height: F32                      # (ny, nx) truth elevation incl. the Cliff-bot body, metres
    albedo: F32                      # (ny, nx) in [0, 1]; constant where textureless
    textureless: NDArray[np.bool_]   # (ny, nx) True where the surface has no texture
    edge_xy: F64                     # (N, 2) true cliff edge polyline; (0, 2) if none
    plateau_z: float                 # the rover's ground height
    rover_start: tuple[float, float, float]  # (x, y, yaw) metres, metres, radians
    safe_side_sign: int
    cliffbot: CliffbotTruth
    map_grid: MapGridConfig          # the FSW map grid that suits this scenario
    ground: F32                      # (ny, nx) terrain without the Cliff-bot (what is ray-traced)
    detail: F32                      # (ny, nx) amplitude of the fine detail texture (0 = none)
    plateau: NDArray[np.bool_]       # (ny, nx) True on the plateau (the safe, drivable side)
    noise_sigma: float = 2.0         # scenario's default camera noise, grey levels
    description: str = ""
    config: Any = field(default=None, repr=False)  # the validated ScenarioConfig
    drawn: dict[str, float] = field(default_factory=dict)  # generator parameters drawn from the seed
    team: TeamTruth | None = None  # anchors, targets and jumble of a team scenario (cliff-team)
    props: tuple[Quad, ...] = ()  # other planar things the cameras see (the Anchorbots' marker plates)

    @property
    def shape(self) -> tuple[int, int]:
        return (int(self.height.shape[0]), int(self.height.shape[1]))

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """``(xmin, xmax, ymin, ymax)`` of the truth grid, metres."""
        ny, nx = self.shape
        return (self.x0, self.x0 + nx * self.cell_m, self.y0, self.y0 + ny * self.cell_m)

    @property
    def z_range(self) -> tuple[float, float]:
        """Lowest and highest point of the terrain (without the Cliff-bot), metres."""
        return (float(self.ground.min()), float(self.ground.max()))

    def height_at(self, x: F64 | float, y: F64 | float) -> F64:
        """Truth elevation at world points (bilinear between cell centres; NaN off the grid)."""
        return self._sample(self.height, x, y)

    def ground_at(self, x: F64 | float, y: F64 | float) -> F64:
        """Terrain elevation without the Cliff-bot (bilinear; NaN off the grid)."""
        return self._sample(self.ground, x, y)

    def on_plateau(self, x: F64 | float, y: F64 | float) -> NDArray[np.bool_]:
        """True where a point is on the plateau (nearest cell; False off the grid)."""
        ix, iy, inside = self._index(x, y)
        out = np.zeros(np.shape(ix), bool)
        out[inside] = self.plateau[iy[inside], ix[inside]]
        return out

    def over_drop(self, x: F64 | float, y: F64 | float, step_m: float) -> NDArray[np.bool_]:
        """True where a point is off the plateau and more than ``step_m`` below the nearest
        plateau ground (on a level plateau: below ``plateau_z - step_m``; on sloped ground the
        drop is measured locally, so driving downhill is not falling off). False off the grid."""
        ix, iy, inside = self._index(x, y)
        out = np.zeros(np.shape(ix), bool)
        z = self._sample(self.ground, x, y)
        ii, jj = iy[inside], ix[inside]
        out[inside] = ~self.plateau[ii, jj] & (z[inside] < self._plateau_ref[ii, jj] - step_m)
        return out

    @functools.cached_property
    def _plateau_ref(self) -> F32:
        """Height of the nearest plateau cell, per truth cell."""
        if not self.plateau.any():
            return np.full(self.ground.shape, self.plateau_z, np.float32)
        idx = ndimage.distance_transform_edt(~self.plateau, return_distances=False,
                                             return_indices=True)
        return np.asarray(self.ground[idx[0], idx[1]], np.float32)

    def truth_on_grid(self, grid: MapGrid, frame: Pose2 = ORIGIN) -> F64:
        """Mean truth elevation over each map cell (docs/algorithm.md §1), ``(ny, nx)``; NaN where
        the map cell is not entirely inside the truth grid. ``frame``: the map frame's origin and
        heading in the world, ``(x, y, yaw)``: the flight map's frame is the RECON-bot's odometry,
        which starts at ``rover_start``."""
        xs, ys, s = self._subsamples(grid, frame)
        z = self._sample(self.height, xs, ys)
        return np.asarray(z.reshape(grid.ny, s, grid.nx, s).mean(axis=(1, 3)), float)

    def ground_on_grid(self, grid: MapGrid, frame: Pose2 = ORIGIN) -> F64:
        """Like :meth:`truth_on_grid`, of the terrain without the Cliff-bot (what a planner
        that knows the ground perfectly plans on)."""
        xs, ys, s = self._subsamples(grid, frame)
        z = self._sample(self.ground, xs, ys)
        return np.asarray(z.reshape(grid.ny, s, grid.nx, s).mean(axis=(1, 3)), float)

    def textureless_on_grid(self, grid: MapGrid, frame: Pose2 = ORIGIN) -> NDArray[np.bool_]:
        """True for map cells mostly (> 50 %) covered by textureless surface."""
        xs, ys, s = self._subsamples(grid, frame)
        ix, iy, inside = self._index(xs, ys)
        t = np.zeros(xs.shape, float)
        t[inside] = self.textureless[iy[inside], ix[inside]]
        return np.asarray(t.reshape(grid.ny, s, grid.nx, s).mean(axis=(1, 3)) > 0.5)

    # -- helpers ------------------------------------------------------------------------
    def _index(self, x: Any, y: Any) -> tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.bool_]]:
        ny, nx = self.shape
        ix = np.floor((np.asarray(x, float) - self.x0) / self.cell_m).astype(np.intp)
        iy = np.floor((np.asarray(y, float) - self.y0) / self.cell_m).astype(np.intp)
        return ix, iy, (ix >= 0) & (ix < nx) & (iy >= 0) & (iy < ny)

    def _sample(self, arr: F32, x: Any, y: Any) -> F64:
        """Exact bilinear interpolation between cell centres; NaN off the grid."""
        xa, ya = np.broadcast_arrays(np.asarray(x, float), np.asarray(y, float))
        ny, nx = self.shape
        px = (xa - self.x0) / self.cell_m - 0.5
        py = (ya - self.y0) / self.cell_m - 0.5
        off = ~((px >= -0.5) & (px <= nx - 0.5) & (py >= -0.5) & (py <= ny - 0.5))
        px = np.clip(np.nan_to_num(px), 0.0, nx - 1.0)
        py = np.clip(np.nan_to_num(py), 0.0, ny - 1.0)
        ix = np.minimum(px.astype(np.intp), nx - 2)
        iy = np.minimum(py.astype(np.intp), ny - 2)
        fx, fy = px - ix, py - iy
        z = ((arr[iy, ix] * (1 - fx) + arr[iy, ix + 1] * fx) * (1 - fy)
             + (arr[iy + 1, ix] * (1 - fx) + arr[iy + 1, ix + 1] * fx) * fy)
        return np.where(off, np.nan, z).astype(float)

    def _subsamples(self, grid: MapGrid, frame: Pose2 = ORIGIN) -> tuple[F64, F64, int]:
        s = max(1, int(np.ceil(grid.cell / self.cell_m - 1e-9)))
        sub = (np.arange(s) + 0.5) / s
        xs = grid.x0 + (np.arange(grid.nx)[:, None] + sub[None, :]).reshape(-1) * grid.cell
        ys = grid.y0 + (np.arange(grid.ny)[:, None] + sub[None, :]).reshape(-1) * grid.cell
        gx, gy = np.meshgrid(xs, ys)
        if tuple(frame) == ORIGIN:
            return gx, gy, s
        x0, y0, yaw = (float(v) for v in frame)
        c, sn = math.cos(yaw), math.sin(yaw)
        return x0 + c * gx - sn * gy, y0 + sn * gx + c * gy, s


def readonly(*arrays: np.ndarray) -> None:
    """Mark arrays read-only (worlds are cached and shared between callers)."""
    for a in arrays:
        a.flags.writeable = False


def aim_at(world: World, rover_xy_yaw: tuple[float, float, float], mast: MastConfig) -> tuple[float, float, float]:
    """Mast joints (pan, tilt, lift 0.3 m) that point the camera at the Cliff-bot's centre."""
    lift = min(max(0.3, mast.lift_min_m), mast.lift_max_m)
    cb = world.cliffbot
    return point_mast(rover_xy_yaw, (cb.x, cb.y, cb.z + 0.5 * cb.height_m), mast, lift, world.plateau_z)[0]
