"""Coarse-to-fine rating of candidate views: the next-view search made fast (docs/algorithm.md §3.1,
§3.2, §3.5).

The exact rating (``nbv.rate_station_steps``) runs the P_V kernel on every cell within reach of
every camera centre: its cost grows with the cells per centre times the ray length in cells,
i.e. faster than the map. Here every centre is first rated on a *decimated* terrain, and only
the few centres whose best coarse utility is highest are rated exactly:

1. :func:`coarsen_terrain`: blocks of ``f x f`` fine cells (``f = round(coarse_cell_m /
   cell_m)``) become one cell. Elevation is the block mean; the block's spread of elevations
   is added to its variance (``s^2 = mean(s_i^2) + var(z_i)``), so a rough block occludes
   like a rough cell; the exponent ``w`` is the block mean times ``f`` (a ray crosses about
   ``f`` times fewer cells, each standing for ``f`` fine factors of Eq 4).
2. :func:`rate_station_coarse_steps`: the kernel runs on the coarse cells holding a fine cell
   worth rating; each fine cell takes its block's P_V; Eq 3's per-cell terms (and the expected
   new cells) are computed per *fine* cell with that P_V, with the fine cell's own ``n`` and
   interest, then summed per block; the field-of-view sums run on the block centres. Cost:
   ``f^2`` fewer targets, rays ``f`` times shorter.
3. The planner (``info_planners``) refines the best ``refine_views`` views with the exact
   rating and chooses among those: the chosen view's H and P_V are the exact kernel's. On a
   map finer than ``[nbv] fine_cell_m`` the refinement runs the kernel on blocks pooled to it
   (:func:`rate_views_pooled_steps`), the cell terms still per map cell.

The coarse cell size is fixed in metres, so the coarse stage costs the same whatever the map's
resolution; only the refined centres grow with it. Measured figures: docs/nbv.md.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Generator
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fsw.core.geometry import CameraConfig, CameraPose, MapGrid
from fsw.core.planning.nbv import AccuracyModel, StationRating, cell_values, view_sums_steps
from fsw.core.planning.visibility import F64, Terrain, VisibilityConfig, horizontal_reach_m, in_view
from fsw.core.planning.visibility_kernel import pv_fast_steps, unique_inverse


def coarse_factor(cell_m: float, coarse_cell_m: float) -> int:
    """Fine cells per coarse cell side: ``round(coarse_cell_m / cell_m)``, at least 1."""
    if not (coarse_cell_m > 0.0 and math.isfinite(coarse_cell_m)):
        return 1
    return max(1, int(round(coarse_cell_m / cell_m)))


def fine_factor(cell_m: float, fine_cell_m: float) -> int:
    """Map cells per side of the refining pass's pooled cell: the most whose block is still no
    larger than ``fine_cell_m`` (``floor(fine_cell_m / cell_m)``), at least 1 (0: the map's cell)."""
    if not (fine_cell_m > 0.0 and math.isfinite(fine_cell_m)):
        return 1
    return max(1, int(math.floor(fine_cell_m / cell_m + 1e-9)))


def _blocks(a: F64, f: int, mode: str) -> F64:
    """``a`` (ny, nx) padded to multiples of ``f`` and viewed as (NY, NX, f*f) blocks."""
    ny, nx = a.shape
    py, px = -ny % f, -nx % f
    if mode == "edge":
        a = np.pad(a, ((0, py), (0, px)), mode="edge")
    else:
        a = np.pad(a, ((0, py), (0, px)), mode="constant", constant_values=0.0)
    big_y, big_x = a.shape[0] // f, a.shape[1] // f
    return a.reshape(big_y, f, big_x, f).transpose(0, 2, 1, 3).reshape(big_y, big_x, f * f)


def coarsen_terrain(terrain: Terrain, f: int) -> Terrain:
    """The terrain on a grid ``f`` times coarser (step 1 of the module docstring)."""
    g = terrain.grid
    if f <= 1:
        return terrain
    z = _blocks(terrain.elev_m, f, "edge")
    s2 = _blocks(terrain.sigma_m**2, f, "edge")
    w = _blocks(terrain.weight, f, "zero")
    elev = z.mean(axis=2)
    sigma = np.sqrt(s2.mean(axis=2) + z.var(axis=2))
    weight = np.minimum(w.mean(axis=2) * f, float(f))
    cg = MapGrid(g.x0, g.y0, g.cell * f, elev.shape[1], elev.shape[0])
    return Terrain(cg, elev, sigma, weight)


@dataclass(frozen=True)
class CoarseSearch:
    """What every centre's coarse rating of one search shares: the coarse terrain and the fine
    cells worth rating (their position, block, ``n`` and interest)."""

    terrain: Terrain  # coarse
    factor: int
    x_m: F64  # fine cells worth rating: centre x, y
    y_m: F64
    block: NDArray[np.intp]  # flat coarse index of each
    n: NDArray[np.int32]
    interest: F64 | None
    n_max: int
    sigma_m: F64 | None = None  # fine elevation sigma of each (with an accuracy model)
    accuracy: AccuracyModel | None = None
    weight: F64 | None = None  # the task's weight of each one's bits (``nbv.cell_values``)
    z_m: F64 | None = None  # fine elevation of each (the refining pass's field-of-view test)


def prepare(terrain: Terrain, factor: int, n: NDArray[np.int32], n_max: int,
            interest: F64 | None, accuracy: AccuracyModel | None = None,
            weight: F64 | None = None) -> CoarseSearch:
    """Coarse terrain and the worth-rating fine cells (``n < n_max``, interest > 0), once per
    search; ``weight``: the task's weight of each cell's bits (``nbv.cell_values``)."""
    g = terrain.grid
    coarse = coarsen_terrain(terrain, factor)
    worth = np.asarray(n) < n_max
    if interest is not None:
        worth &= np.asarray(interest) > 0
    iy, ix = np.nonzero(worth)
    block = (iy // factor) * coarse.grid.nx + ix // factor
    x_m = np.asarray(g.x0 + (ix + 0.5) * g.cell, dtype=np.float64)
    y_m = np.asarray(g.y0 + (iy + 0.5) * g.cell, dtype=np.float64)
    return CoarseSearch(coarse, factor, x_m, y_m,
                        block.astype(np.intp), np.asarray(n)[iy, ix].astype(np.int32),
                        None if interest is None else np.asarray(interest)[iy, ix], n_max,
                        None if accuracy is None else terrain.sigma_m[iy, ix], accuracy,
                        None if weight is None else np.asarray(weight, np.float64)[iy, ix],
                        np.asarray(terrain.elev_m[iy, ix], dtype=np.float64))


def _block_values_steps(cs: CoarseSearch, cam_xyz: tuple[float, float, float], cells: NDArray[np.intp],
                        cfg: VisibilityConfig
                        ) -> Generator[None, None, tuple[F64, F64, NDArray[np.int64], NDArray[np.intp]]]:
    """Eq 3's bits and the expected new cells of the map cells ``cells`` of ``cs``, each with its
    block's P_V (the kernel on the pooled terrain): (bits, new, the blocks, each cell's block)."""
    cg = cs.terrain.grid
    blocks, inverse = unique_inverse(cs.block[cells], cg.nx * cg.ny)
    by, bx = np.divmod(blocks, cg.nx)
    pv_block = yield from pv_fast_steps(cs.terrain, cam_xyz, by, bx, cfg)
    bits, new = cell_values(pv_block[inverse], cs.n[cells], cs.n_max,
                            None if cs.interest is None else cs.interest[cells],
                            stereo_return=cfg.stereo_return,
                            weight=None if cs.weight is None else cs.weight[cells])
    return bits, new, blocks, inverse


def rate_station_coarse_steps(cs: CoarseSearch, cam_xyz: tuple[float, float, float], yaws: F64,
                              tilts: F64, camera: CameraConfig, cfg: VisibilityConfig
                              ) -> Generator[None, None, StationRating]:
    """``nbv.rate_station_steps`` on the coarse terrain (step 2 of the module docstring):
    (P, T) arrays of H (bits) and expected new cells, in bounded steps."""
    reach = horizontal_reach_m(camera)
    near = np.flatnonzero((cs.x_m - cam_xyz[0]) ** 2 + (cs.y_m - cam_xyz[1]) ** 2 <= reach**2)
    if near.size == 0:
        zero = np.zeros((yaws.size, tilts.size))
        return StationRating(zero, zero.copy(), 0)
    cg = cs.terrain.grid
    bits, new, blocks, inverse = yield from _block_values_steps(cs, cam_xyz, near, cfg)
    by, bx = np.divmod(blocks, cg.nx)
    if cs.accuracy is not None and cs.sigma_m is not None:
        rel_f = np.column_stack([cs.x_m[near] - cam_xyz[0], cs.y_m[near] - cam_xyz[1],
                                 cs.terrain.elev_m[by, bx][inverse] - cam_xyz[2]])
        bits = bits * cs.accuracy.share(rel_f, cs.sigma_m[near])
    bits_b = np.bincount(inverse, weights=bits, minlength=blocks.size)
    new_b = np.bincount(inverse, weights=new, minlength=blocks.size)
    keep = (bits_b > 1e-6) | (new_b > 1e-6)
    rel = np.column_stack([cg.x0 + (bx[keep] + 0.5) * cg.cell - cam_xyz[0],
                           cg.y0 + (by[keep] + 0.5) * cg.cell - cam_xyz[1],
                           cs.terrain.elev_m[by[keep], bx[keep]] - cam_xyz[2]])
    sums = yield from view_sums_steps(rel, np.column_stack([bits_b[keep], new_b[keep]]), yaws,
                                      tilts, camera)
    return StationRating(sums[..., 0], sums[..., 1], int(near.size))


def coarse_visibility(cfg: VisibilityConfig, factor: int) -> VisibilityConfig:
    """The kernel settings on the coarse grid: ``factor`` times fewer angular bins (the same
    arc per bin against ``factor`` times wider cells), at least 256. With ``ray_cell_m`` set the
    kernel already scales its bins with the cell size, so the settings are kept as they are."""
    if cfg.ray_cell_m > 0.0:
        return cfg
    return dataclasses.replace(cfg, rays_per_turn=max(256, cfg.rays_per_turn // max(1, factor)))


@dataclass(frozen=True)
class ViewRating:
    """Exact H (bits) and expected new cells of K views sharing one camera centre: arrays (K,)."""

    info_bits: F64
    expected_new_cells: F64
    cells_rated: int


def _view_masks_steps(cam_xyz: tuple[float, float, float], yaws: F64, tilts: F64,
                      camera: CameraConfig, pts: F64) -> Generator[None, None, NDArray[np.bool_]]:
    """(K, N) which of the points ``pts`` lie inside each of the K views, a step per view."""
    masks = np.zeros((yaws.size, pts.shape[0]), bool)
    for k in range(yaws.size):
        yield None
        pose = CameraPose.from_pan_tilt(*cam_xyz, float(yaws[k]), float(tilts[k]))
        masks[k] = in_view(pose, camera, pts)
    yield None
    return masks


def _view_sums(masks: NDArray[np.bool_], bits: F64, new: F64) -> ViewRating:
    """H and expected new cells of each view: the sums of the cells' terms inside it."""
    info = np.array([bits[m].sum() for m in masks], dtype=np.float64).reshape(-1)
    new_cells = np.array([new[m].sum() for m in masks], dtype=np.float64).reshape(-1)
    return ViewRating(info, new_cells, int(bits.size))


def rate_views_steps(terrain: Terrain, cam_xyz: tuple[float, float, float], yaws: F64,
                     tilts: F64, n: NDArray[np.int32], n_max: int, interest: F64 | None,
                     camera: CameraConfig, cfg: VisibilityConfig,
                     accuracy: AccuracyModel | None = None, weight: F64 | None = None
                     ) -> Generator[None, None, ViewRating]:
    """Exact rating (§3.1, §3.2) of the K views ``(yaws[k], tilts[k])`` from one centre: the
    fine kernel runs only on cells worth rating inside at least one of them (step 3)."""
    g = terrain.grid
    reach = horizontal_reach_m(camera)
    x_c = g.x0 + (np.arange(g.nx) + 0.5) * g.cell
    y_c = g.y0 + (np.arange(g.ny) + 0.5) * g.cell
    near = ((x_c[None, :] - cam_xyz[0]) ** 2 + (y_c[:, None] - cam_xyz[1]) ** 2) <= reach**2
    worth = near & (np.asarray(n) < n_max)
    if interest is not None:
        worth &= np.asarray(interest) > 0
    iy, ix = np.nonzero(worth)
    pts = np.column_stack([x_c[ix], y_c[iy], terrain.elev_m[iy, ix]])
    masks = yield from _view_masks_steps(cam_xyz, yaws, tilts, camera, pts)
    sel = np.flatnonzero(masks.any(axis=0))
    if sel.size == 0:
        return ViewRating(np.zeros(yaws.size), np.zeros(yaws.size), 0)
    pv = yield from pv_fast_steps(terrain, cam_xyz, iy[sel], ix[sel], cfg)
    bits, new = cell_values(pv, np.asarray(n)[iy[sel], ix[sel]], n_max,
                            None if interest is None else np.asarray(interest)[iy[sel], ix[sel]],
                            stereo_return=cfg.stereo_return,
                            weight=None if weight is None else np.asarray(weight)[iy[sel], ix[sel]])
    if accuracy is not None:
        bits = bits * accuracy.share(pts[sel] - np.asarray(cam_xyz), terrain.sigma_m[iy[sel], ix[sel]])
    yield None  # the sums are a step of their own, apart from what the caller does next
    return _view_sums(masks[:, sel], bits, new)


def rate_views_pooled_steps(cs: CoarseSearch, cam_xyz: tuple[float, float, float], yaws: F64,
                            tilts: F64, camera: CameraConfig, cfg: VisibilityConfig
                            ) -> Generator[None, None, ViewRating]:
    """:func:`rate_views_steps` on a map finer than ``[nbv] fine_cell_m`` (step 3 at a bounded
    resolution): P_V is the kernel's on the pooled terrain of ``cs`` (blocks of ``fine_cell_m``),
    and Eq 3's terms, the expected new cells and the field-of-view sums stay per map cell, with
    the cell's own ``n``, interest, weight and elevation. A P_V of blocks a stereo pixel does
    not resolve costs 8x per halving of the cell and changes no choice the pixel could."""
    reach = horizontal_reach_m(camera)
    near = np.flatnonzero((cs.x_m - cam_xyz[0]) ** 2 + (cs.y_m - cam_xyz[1]) ** 2 <= reach**2)
    if near.size == 0 or cs.z_m is None:
        return ViewRating(np.zeros(yaws.size), np.zeros(yaws.size), 0)
    pts = np.column_stack([cs.x_m[near], cs.y_m[near], cs.z_m[near]])
    masks = yield from _view_masks_steps(cam_xyz, yaws, tilts, camera, pts)
    sel = np.flatnonzero(masks.any(axis=0))
    if sel.size == 0:
        return ViewRating(np.zeros(yaws.size), np.zeros(yaws.size), 0)
    cells = near[sel]
    bits, new, _, _ = yield from _block_values_steps(cs, cam_xyz, cells, cfg)
    if cs.accuracy is not None and cs.sigma_m is not None:
        bits = bits * cs.accuracy.share(pts[sel] - np.asarray(cam_xyz), cs.sigma_m[cells])
    yield None  # the sums are a step of their own, apart from what the caller does next
    return _view_sums(masks[:, sel], bits, new)
