"""Probability that a map cell is visible from a camera centre (docs/algorithm.md §3.1, paper Eq 4).

Model (as implemented; the fast kernel in ``visibility_kernel`` and the reference here compute
the same quantity):

* The ray runs from the target cell's centre, at the cell's elevation, straight to the camera
  centre. It crosses a set of grid cells (the exact "supercover" traversal: every cell whose
  interior the segment enters, corner touches excluded). The target cell itself is not a
  factor, and cells outside the map contribute nothing (factor 1).
* Each crossed cell ``x`` contributes ``Phi((ray(x) - Ob(x)) / s(x)) ** w(x)``, where
  ``ray(x)`` is the ray height at the midpoint of the segment inside the cell, ``Phi`` the
  standard normal CDF, ``Ob`` and ``s`` the cell's elevation and standard deviation:
  ``P_V = prod_x Phi(...) ** w(x)``.
* Known cells (``n >= 1``): ``Ob = z``, ``s = sqrt(var)`` (floored at ``min_sigma_m``), ``w = 1``:
  exactly paper Eq 4.
* Unknown cells, **(choice, §3.1)**: ``Ob`` is a prior elevation interpolated from the known
  cells (Gaussian-weighted mean of known elevations within ~``prior_smooth_m``, nearest known
  value farther out, ``default_elevation_m`` on an empty map), ``s = prior_sigma_m``, and
  ``w = cell_m / prior_corr_len_m``. The exponent treats unknown terrain as correlated over
  ``prior_corr_len_m`` instead of as independent 3 cm cells: with ``w = 1`` a ray grazing
  a metre of unknown ground would multiply ~30 factors near 0.5 and every cell beyond the
  frontier would read as invisible, so views into unmapped terrain would never be chosen.
  ``prior_corr_len_m = cell_m`` restores the literal per-cell product.

Field-of-view and depth-of-field culling (``P_V = 0`` outside) is :func:`in_view` for one pose
and ``nbv`` for pan/tilt batches. :func:`pv_reference` is the brute-force oracle kept for tests
and ``safer-hil bench nbv``; production code calls ``visibility_kernel.pv_fast``.
"""

from __future__ import annotations

import math
from collections.abc import Generator
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from fsw.core.geometry import CameraConfig, CameraPose, MapGrid
from fsw.core.steps import run_to_end
from fsw.framework.params import param

F64 = NDArray[np.float64]
F32 = NDArray[np.float32]
IDX = NDArray[np.intp]


@dataclass(frozen=True)
class VisibilityConfig:
    """P_V model and fast-kernel parameters (config ``[nbv.visibility]``)."""

    prior_sigma_m: float = param(
        0.25, lo=0.001, hi=10.0, units="m", doc="sigma of an unknown cell's prior elevation")
    prior_smooth_m: float = param(
        0.3, lo=0.0, hi=10.0, units="m", doc="radius of the prior's interpolation of known cells")
    prior_corr_len_m: float = param(
        1.0, lo=0.001, hi=100.0, units="m",
        doc="correlation length of unknown terrain; unknown factors get exponent cell/this")
    default_elevation_m: float = param(
        0.0, lo=-1000.0, hi=1000.0, units="m", doc="prior elevation when nothing is mapped")
    min_sigma_m: float = param(
        0.002, lo=1e-5, hi=1.0, units="m", doc="floor on a known cell's elevation sigma")
    rays_per_turn: int = param(
        4096, lo=256, hi=65536, doc="fast kernel: angular bins per full turn (at ray_cell_m)")
    ray_cell_m: float = param(
        0.03, lo=0.0, hi=10.0, units="m",
        doc="cell size at which rays_per_turn holds; the bins scale as 1/cell (0 = fixed)")
    prune_z: float = param(
        4.0, lo=2.0, hi=10.0, units="sigma",
        doc="fast kernel: skips samples whose clearance exceeds this (factor > 0.99997)")
    stereo_return: float = param(
        0.8, lo=0.01, hi=1.0,
        doc="fraction of the unmapped cells a view leaves visible (P_V) that the stereo maps; "
            "scales the expected new cells, not H")


def rays_for_cell(cfg: VisibilityConfig, cell_m: float) -> int:
    """Angular bins per turn of the fast kernel on cells of ``cell_m``: ``rays_per_turn`` at
    ``ray_cell_m``, scaled as 1/cell so a bin's centre ray passes within the same fraction of a
    cell of its targets at any map resolution (256..65536; fixed when ``ray_cell_m`` is 0)."""
    if cfg.ray_cell_m <= 0.0 or not math.isfinite(cell_m) or cell_m <= 0.0:
        return int(cfg.rays_per_turn)
    return int(min(65536, max(256, round(cfg.rays_per_turn * cfg.ray_cell_m / cell_m))))


class Terrain:
    """What the visibility model sees: per-cell elevation ``elev_m``, ``sigma_m``, ``weight``.

    ``packed()`` holds the per-cell constants of the fast kernel, flattened with one extra
    dummy cell (index ``ncell``) that stands for "outside the map" (factor 1).
    """

    def __init__(self, grid: MapGrid, elev_m: F64, sigma_m: F64, weight: F64) -> None:
        if not (elev_m.shape == sigma_m.shape == weight.shape == grid.shape):
            raise ValueError("terrain arrays must all have the grid's shape")
        if not (np.isfinite(elev_m).all() and (sigma_m > 0).all() and np.isfinite(sigma_m).all()):
            raise ValueError("terrain elevation must be finite and sigma finite and positive")
        self.grid = grid
        self.elev_m = elev_m
        self.sigma_m = sigma_m
        self.weight = weight
        self._packed: tuple[F32, F32, F32] | None = None

    def packed(self) -> tuple[F32, F32, F32]:
        """``(1/s, -Ob/s, w)`` per flat cell plus the dummy ``(1, +1e9, 0)``, float32."""
        if self._packed is None:
            inv = np.append((1.0 / self.sigma_m).ravel(), 1.0).astype(np.float32)
            off = np.append((-self.elev_m / self.sigma_m).ravel(), 1e9).astype(np.float32)
            w = np.append(self.weight.ravel(), 0.0).astype(np.float32)
            self._packed = (inv, off, w)
        return self._packed


def prior_elevation(z: F64, grid: MapGrid, cfg: VisibilityConfig) -> F64:
    """Unknown cells filled from known neighbours (§3.1 choice); known cells unchanged."""
    return run_to_end(prior_elevation_steps(z, grid, cfg))


def prior_elevation_steps(z: F64, grid: MapGrid, cfg: VisibilityConfig
                          ) -> Generator[None, None, F64]:
    """:func:`prior_elevation`, yielding between its filters (each a few ms at 512 x 512)."""
    known = np.isfinite(z)
    if not known.any():
        return np.full(grid.shape, cfg.default_elevation_m)
    zk = np.where(known, z, 0.0)
    _, (iy, ix) = ndimage.distance_transform_edt(~known, return_indices=True)
    fill = zk[iy, ix]
    if cfg.prior_smooth_m > 0:
        yield None
        sg = cfg.prior_smooth_m / grid.cell / 2.0
        num = ndimage.gaussian_filter(zk, sg, mode="nearest", truncate=2.0)
        yield None
        den = ndimage.gaussian_filter(known.astype(np.float64), sg, mode="nearest", truncate=2.0)
        fill = np.where(den > 1e-3, num / np.maximum(den, 1e-12), fill)
    return np.where(known, z, fill)


def terrain_from_map(z: F64, var: F64, grid: MapGrid, cfg: VisibilityConfig) -> Terrain:
    """Terrain of the visibility model for a map with ``z`` (NaN unknown) and ``var`` (inf)."""
    return run_to_end(terrain_from_map_steps(z, var, grid, cfg))


def terrain_from_map_steps(z: F64, var: F64, grid: MapGrid, cfg: VisibilityConfig
                           ) -> Generator[None, None, Terrain]:
    """:func:`terrain_from_map` in bounded steps (for the search's slack job)."""
    known = np.isfinite(z) & np.isfinite(var)
    zz = np.where(known, z, np.nan)
    elev = yield from prior_elevation_steps(zz, grid, cfg)
    yield None
    sig_known = np.sqrt(np.maximum(np.where(known, var, 0.0), cfg.min_sigma_m**2))
    sigma = np.where(known, sig_known, cfg.prior_sigma_m)
    weight = np.where(known, 1.0, min(1.0, grid.cell / cfg.prior_corr_len_m))
    return Terrain(grid, elev, sigma, weight)


def terrain_from_heights(height_m: F64, grid: MapGrid, sigma_m: float) -> Terrain:
    """Fully known terrain (truth for the oracle planner, synthetic tests)."""
    h = np.asarray(height_m, dtype=np.float64)
    return Terrain(grid, h, np.full(grid.shape, float(sigma_m)), np.ones(grid.shape))


def horizontal_reach_m(camera: CameraConfig) -> float:
    """Largest horizontal distance of any point inside the depth of field (frustum corner)."""
    tan_h = math.tan(math.radians(camera.hfov_deg) / 2.0)
    tan_v = math.tan(camera.vfov_rad / 2.0)
    return camera.max_range_m * math.sqrt(1.0 + tan_h**2 + tan_v**2)


def in_view(pose: CameraPose, camera: CameraConfig, pts_w: F64) -> NDArray[np.bool_]:
    """Points ``(N, 3)`` inside the image and the usable depth range (§3.1 culling)."""
    rel = np.asarray(pts_w, dtype=np.float64).reshape(-1, 3) - pose.t
    pc = np.einsum("nj,jk->nk", rel, pose.R)  # = world_to_camera, without threaded BLAS
    x, y, zc = pc[:, 0], pc[:, 1], pc[:, 2]
    tan_h = math.tan(math.radians(camera.hfov_deg) / 2.0)
    tan_v = math.tan(camera.vfov_rad / 2.0)
    return ((zc >= camera.min_range_m) & (zc <= camera.max_range_m)
            & (np.abs(x) <= zc * tan_h) & (np.abs(y) <= zc * tan_v))


def cell_points(terrain: Terrain, iy: IDX, ix: IDX) -> F64:
    """World points ``(N, 3)``: cell centres at the terrain elevation."""
    g = terrain.grid
    return np.column_stack([g.x0 + (ix + 0.5) * g.cell, g.y0 + (iy + 0.5) * g.cell,
                            terrain.elev_m[iy, ix]])
