"""Shared steps of building a scenario's :class:`World` (docs/world.md, "Scenarios").

Every scenario generator makes a terrain ``ground`` on a truth grid, then calls
:func:`finish_world`, which places the Cliff-bot, writes its body into the 2.5D truth,
generates the albedo texture, finds the plateau and freezes the arrays.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from fsw.core.geometry import MapGridConfig
from hil_sim.world.cliffbot import build_cliffbot
from hil_sim.world.config import ScenarioConfig, ScenarioError
from hil_sim.world.noise import smooth_curve
from hil_sim.world.texture import make_texture
from hil_sim.world.world import World, readonly

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]


@dataclass(frozen=True)
class TruthGrid:
    """Coordinates of the truth grid's cell centres."""

    x0: float
    y0: float
    cell_m: float
    nx: int
    ny: int

    @property
    def xs(self) -> F64:
        return np.asarray(self.x0 + (np.arange(self.nx) + 0.5) * self.cell_m, np.float64)

    @property
    def ys(self) -> F64:
        return np.asarray(self.y0 + (np.arange(self.ny) + 0.5) * self.cell_m, np.float64)

    def mesh(self) -> tuple[F32, F32]:
        gx, gy = np.meshgrid(self.xs.astype(np.float32), self.ys.astype(np.float32))
        return gx, gy


def truth_grid(cfg: ScenarioConfig) -> TruthGrid:
    w = cfg.world
    ny, nx = w.shape
    return TruthGrid(w.x_min_m, w.y_min_m, w.cell_m, nx, ny)


def textureless_mask(grid: TruthGrid, regions: tuple[tuple[float, float, float, float], ...],
                     seed: int) -> NDArray[np.bool_]:
    """True inside the ``[texture] textureless_regions``: each an ellipse (centre x, y;
    semi-axes rx, ry) whose radius is modulated by a few random harmonics, so the boundary is
    irregular like a patch of fine sand or silt. Each region draws from its own stream
    (``seed``, region index), so adding one leaves the rest of the world unchanged."""
    gx, gy = grid.mesh()
    mask = np.zeros(gx.shape, bool)
    for i, (x, y, rx, ry) in enumerate(regions):
        if rx <= 0.0 or ry <= 0.0:
            raise ScenarioError(f"textureless region {i}: semi-axes must be > 0, got {rx}, {ry}")
        rng = np.random.default_rng([seed, 11, i])
        u, v = (gx - x) / rx, (gy - y) / ry
        theta = np.arctan2(v, u)
        wobble = np.zeros_like(theta)
        for harmonic in (2, 3, 5):
            wobble += rng.uniform(0.04, 0.1) * np.cos(harmonic * theta + rng.uniform(0, 2 * np.pi))
        mask |= np.hypot(u, v) < 1.0 + wobble
    return mask


def dilate(mask: NDArray[np.bool_], cells: int) -> NDArray[np.bool_]:
    """``mask`` grown by a disc of ``cells`` radius."""
    import cv2

    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * cells + 1, 2 * cells + 1))
    return np.asarray(cv2.dilate(mask.astype(np.uint8), k).astype(bool))


def edge_curve(xs: F64, rng: np.random.Generator, mean_y: float, wiggle_m: float,
               wavelength_m: float) -> F64:
    """An irregular edge line ``y(x)`` sampled at ``xs`` (a smooth random curve)."""
    step = float(xs[1] - xs[0]) if xs.size > 1 else 0.01
    return np.asarray(mean_y + wiggle_m * smooth_curve(xs.size, step, rng,
                                                       wavelength_m=wavelength_m), float)


def finish_world(
    cfg: ScenarioConfig,
    name: str,
    seed: int,
    grid: TruthGrid,
    ground: F32,
    rng: np.random.Generator,
    *,
    edge_xy: F64,
    plateau_z: float,
    rock_id: NDArray[np.int32] | None = None,
    textureless: NDArray[np.bool_] | None = None,  # None: the [texture] regions everywhere
    map_grid: MapGridConfig | None = None,
    plateau_tol_m: float = 0.01,
    plateau: NDArray[np.bool_] | None = None,  # None: level ground within plateau_tol_m
) -> World:
    """Place the Cliff-bot, texture the ground and assemble the read-only :class:`World`."""
    ground = np.ascontiguousarray(ground, dtype=np.float32)
    if not np.isfinite(ground).all():
        raise ScenarioError(f"{name}: the terrain has non-finite heights")
    rs = cfg.rover_start
    cb = cfg.cliffbot
    yaw = math.radians(cb.yaw_deg)
    if cb.yaw_mode == "face_rover":
        yaw += math.atan2(rs.y_m - cb.y_m, rs.x_m - cb.x_m)
    foot = _footprint_heights(grid, ground, cb.x_m, cb.y_m, 0.5 * max(cb.length_m, cb.width_m))
    if foot.size == 0:
        raise ScenarioError(f"{name}: the Cliff-bot at ({cb.x_m}, {cb.y_m}) is off the world")
    cliffbot = build_cliffbot(cb.x_m, cb.y_m, float(np.median(foot)), yaw,
                              size_m=(cb.length_m, cb.width_m, cb.height_m),
                              marker_size_m=cb.marker_size_m, marker_ids=cb.marker_ids,
                              seed=seed)
    height = ground.copy()
    cliffbot.stamp_height(height, grid.x0, grid.y0, grid.cell_m)
    if textureless is None:
        textureless = textureless_mask(grid, cfg.texture.textureless_regions, seed)
    albedo, detail = make_texture(ground, grid.cell_m, cfg.texture, rng, rock_id=rock_id,
                                  textureless=textureless)
    if plateau is None:
        plateau = plateau_mask(grid, ground, (rs.x_m, rs.y_m), plateau_z, plateau_tol_m)
    readonly(height, ground, albedo, detail, textureless, plateau)
    edge = np.asarray(edge_xy, float).reshape(-1, 2)
    readonly(edge)
    return World(
        name=name, seed=seed, x0=grid.x0, y0=grid.y0, cell_m=grid.cell_m, height=height,
        albedo=albedo, textureless=textureless, edge_xy=edge, plateau_z=float(plateau_z),
        rover_start=(rs.x_m, rs.y_m, math.radians(rs.yaw_deg)), safe_side_sign=1,
        cliffbot=cliffbot, map_grid=map_grid or cfg.map, ground=ground, detail=detail,
        plateau=plateau, noise_sigma=cfg.scenario.noise_sigma,
        description=cfg.scenario.description, config=cfg)


def plateau_mask(grid: TruthGrid, ground: F32, start_xy: tuple[float, float], plateau_z: float,
                 tol_m: float) -> NDArray[np.bool_]:
    """Cells within ``tol_m`` of ``plateau_z`` connected to the rover's start cell."""
    level = np.abs(ground - plateau_z) <= tol_m
    labels, _ = ndimage.label(level)
    ix = int((start_xy[0] - grid.x0) / grid.cell_m)
    iy = int((start_xy[1] - grid.y0) / grid.cell_m)
    if not (0 <= ix < grid.nx and 0 <= iy < grid.ny) or labels[iy, ix] == 0:
        raise ScenarioError(f"the rover start {start_xy} is not on level ground of the world")
    return np.asarray(labels == labels[iy, ix])


def slope_plateau(grid: TruthGrid, ground: F32, start_xy: tuple[float, float],
                  max_slope_deg: float) -> NDArray[np.bool_]:
    """The rover's ground on sloped terrain: cells connected to the start cell through
    neighbour steps no steeper than ``max_slope_deg`` (a cliff face or a rock flank breaks the
    connection, a regional slope does not), with enclosed holes (rocks standing on it) filled."""
    ix = int((start_xy[0] - grid.x0) / grid.cell_m)
    iy = int((start_xy[1] - grid.y0) / grid.cell_m)
    if not (0 <= ix < grid.nx and 0 <= iy < grid.ny):
        raise ScenarioError(f"the rover start {start_xy} is off the world")
    max_step = math.tan(math.radians(max_slope_deg)) * grid.cell_m
    gx = np.abs(np.diff(ground, axis=1)) > max_step  # steep between (iy, ix) and (iy, ix + 1)
    gy = np.abs(np.diff(ground, axis=0)) > max_step
    steep = np.zeros(ground.shape, bool)  # a cell touching a steep step is a boundary cell
    steep[:, :-1] |= gx
    steep[:, 1:] |= gx
    steep[:-1, :] |= gy
    steep[1:, :] |= gy
    labels, _ = ndimage.label(~steep)
    if labels[iy, ix] == 0:
        raise ScenarioError(f"the rover start {start_xy} is on ground steeper than "
                            f"{max_slope_deg:g} deg")
    return np.asarray(ndimage.binary_fill_holes(labels == labels[iy, ix]), bool)


def _footprint_heights(grid: TruthGrid, ground: F32, x: float, y: float, r: float) -> F32:
    ix0, ix1 = int((x - r - grid.x0) / grid.cell_m), int((x + r - grid.x0) / grid.cell_m) + 1
    iy0, iy1 = int((y - r - grid.y0) / grid.cell_m), int((y + r - grid.y0) / grid.cell_m) + 1
    ix0, iy0 = max(ix0, 0), max(iy0, 0)
    return ground[iy0:min(iy1, grid.ny), ix0:min(ix1, grid.nx)].reshape(-1)
