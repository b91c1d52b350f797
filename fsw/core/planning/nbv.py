"""Rating of candidate views: information, motion, localization, utility (docs/algorithm.md §3).

* Expected new information of a pose (§3.2, paper Eq 3), with the interest function (§3.4,
  Eq 5) pre-multiplied into the visibility when the method uses it:
  ``H(c) = sum_{i in view(c)} (n_max - n_i)/n_max * h2(IF_i * P_V(i) / 2)``, bits. Eq 3's
  ``n_max`` is ``info_n_max`` (default 2: a cell seen once is worth half a new one, twice
  nothing), not the map's fusion cap (10), under which a cell seen once would still be worth
  90 % of an unmapped one and the planner would rather re-measure than explore.
  Alongside it, ``expected_new_cells = rho * sum_{i in view(c), n_i = 0} P_V(i)``: the
  expected number of cells the view maps for the first time (what the paper's Figure 8 plots
  against the obtained count), with ``rho`` the stereo's return (``[nbv.visibility]
  stereo_return``: P_V is an ideal view's visibility, the stereo maps a fraction of it). The
  interest ranks views (it is in H) but is not in the count: a cell's interest is no
  probability that it is mapped.
* Motion cost (§3.3, Eq 9): ``d = sqrt(sum_i a_i (c_i - c'_i)^2)`` over (x, y, yaw, pan,
  tilt, lift); default ``a_i`` are 1/rate^2 so ``d`` is about the seconds of motion.
* Localization term (§3.5): ``sigma_loc`` = odometry drift grown over the path travelled,
  fused with a fiducial fix when a landmark (the Cliff-bot's markers, §5) is in view and in
  range (PnP error grows with range^2).
* Utility (§3.5 choice): ``U = H - w_d d - w_l sigma_loc``.
* End criterion (§3.6): :func:`end_reason`.

Rating is per *station* (a camera centre): ``visibility_kernel.pv_fast`` gives P_V of every
cell the station could see, once; each pan/tilt then only masks those cells by its field of
view and depth of field (:func:`view_sums`). The ``*_steps`` generators do the same work in
bounded steps of a few milliseconds for the executive's slack jobs.
"""

from __future__ import annotations

import math
from collections.abc import Generator
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from fsw.core.geometry import CameraConfig, CameraPose, MapGrid, wrap_angle
from fsw.core.planning.visibility import (
    F64,
    Terrain,
    VisibilityConfig,
    horizontal_reach_m,
    in_view,
    terrain_from_map,
)
from fsw.core.planning.visibility_kernel import pv_fast_steps
from fsw.core.steps import run_to_end
from fsw.framework.params import param


class MapLike(Protocol):
    """What rating reads from ``fsw.core.map.elevation_map.ElevationMap``."""

    grid: MapGrid
    z: F64
    var: F64
    n: NDArray[np.int32]
    interest: F64
    n_max: int


@dataclass(frozen=True)
class NbvConfig:
    """Next-view selection (config ``[nbv]``); see docs/nbv.md for the reasoning."""

    w_motion: float = param(5.0, lo=0.0, hi=1e6, units="bit/s", doc="w_d: bits per unit of d")
    w_loc: float = param(2000.0, lo=0.0, hi=1e9, units="bit/m", doc="w_l: bits per m of sigma_loc")
    a_xy: float = param(25.0, lo=0.0, hi=1e6, units="s^2/m^2", doc="Eq 9 weight of x and y")
    a_yaw: float = param(8.2, lo=0.0, hi=1e6, units="s^2/rad^2", doc="Eq 9 weight of rover yaw")
    a_pan: float = param(3.65, lo=0.0, hi=1e6, units="s^2/rad^2", doc="Eq 9 weight of mast pan")
    a_tilt: float = param(3.65, lo=0.0, hi=1e6, units="s^2/rad^2", doc="Eq 9 weight of tilt")
    a_lift: float = param(400.0, lo=0.0, hi=1e6, units="s^2/m^2", doc="Eq 9 weight of lift")
    info_n_max: int = param(2, lo=0, hi=100000,
                            doc="n_max of Eq 3's weight (n_max - n)/n_max; 0: the map's n_max")
    station_spacing_m: float = param(0.25, lo=0.01, hi=10.0, units="m", doc="stations on the path")
    max_travel_m: float = param(2.5, lo=0.0, hi=100.0, units="m", doc="farthest station per step")
    pan_step_deg: float = param(20.0, lo=1.0, hi=180.0, units="deg", doc="pan grid step")
    tilts_deg: tuple[float, ...] = param((-15.0, -30.0, -45.0, -60.0), units="deg",
                                         doc="tilt grid (within the mast limits)")
    lifts_m: tuple[float, ...] = param((0.5,), units="m", doc="lift grid (within the limits)")
    odo_drift_frac: float = param(0.01, lo=0.0, hi=1.0, units="m/m",
                                  doc="localization sigma grown per metre travelled")
    fiducial_sigma_1m_m: float = param(0.002, lo=1e-6, hi=1.0, units="m",
                                       doc="fiducial fix sigma at 1 m (grows with range^2)")
    fiducial_range_m: float = param(4.0, lo=0.1, hi=100.0, units="m",
                                    doc="farthest usable fiducial")
    max_steps: int = param(20, lo=1, hi=100000, doc="end criterion: imaging step limit")
    min_info_bits: float = param(20.0, lo=0.0, hi=1e9, units="bit",
                                 doc="end criterion: stop when the best H falls below")
    target_mapped_fraction: float = param(0.98, lo=0.0, hi=1.0,
                                          doc="end criterion: mapped fraction of the ROI")
    raster_overlap_frac: float = param(0.1, lo=0.0, hi=0.9,
                                       doc="raster: overlap of consecutive views along the path")
    raster_pans_per_station: int = param(3, lo=1, hi=36, doc="Method 2: pan views per station")
    raster_floor_drop_m: float = param(0.4, lo=0.0, hi=100.0, units="m",
                                       doc="raster: assumed ROI floor below the rover when unmapped")
    oracle_sigma_m: float = param(0.005, lo=1e-4, hi=1.0, units="m",
                                  doc="oracle: sigma given to the true terrain")
    coarse_cell_m: float = param(0.12, lo=0.0, hi=10.0, units="m",
                                 doc="coarse-to-fine search: coarse cell size (0: rate exactly)")
    refine_views: int = param(12, lo=1, hi=100000,
                              doc="coarse-to-fine search: best coarse views rated exactly")
    fine_cell_m: float = param(
        0.03, lo=0.0, hi=10.0, units="m",
        doc="coarse-to-fine search: the finest cell the refining pass resolves P_V on; a finer map is "
            "pooled to it there (its cells keep their own n, interest and weight; 0: the map's cell; §3.5 choice)")
    leave_start_edge_m: float = param(
        1.2, lo=0.0, hi=100.0, units="m",
        doc="a start is boxed in by a close edge when the fitted edge passes within this of the rover's "
            "centre (the path's setback or nearer, with the fit's error; 0: the rule is off; §3 choice)")
    leave_start_tol: float = param(
        0.25, lo=0.0, hi=1.0,
        doc="a boxed-in start is left for the best reachable station unless the views from the start "
            "rate more than this share above it (the information model's resolution; §3 choice)")
    accuracy_sigma_m: float = param(
        0.0, lo=0.0, hi=1.0, units="m",
        doc="Method 5: weigh each cell's bits by the share of its variance the view removes, against "
            "min(var, this^2) (0: off; §3.2 choice)")
    accuracy_disparity_px: float = param(0.5, lo=0.01, hi=10.0, units="px",
                                         doc="Method 5 accuracy weight: disparity sigma of a view's point")
    focus_regions: tuple[tuple[float, ...], ...] = param(
        (), doc="regions a task needs mapped (§3.4): (x_min, y_min, x_max, y_max, weight) rows, map frame, m; "
                "the interest of their cells is weighted by weight >= 1")
    visibility: VisibilityConfig = field(default_factory=VisibilityConfig)

    def __post_init__(self) -> None:
        for row in self.focus_regions:
            if len(row) != 5 or not all(math.isfinite(v) for v in row):
                raise ValueError("each focus region needs 5 finite numbers (x_min, y_min, x_max, y_max, weight)")
            if not (row[0] < row[2] and row[1] < row[3]) or not 1.0 <= row[4] <= 100.0:
                raise ValueError(f"focus region {list(row)}: needs x_min < x_max, y_min < y_max, 1 <= weight <= 100")


def focus_weights(grid: MapGrid, regions: tuple[tuple[float, ...], ...]) -> F64:
    """The task's weight of each cell (§3.4): 1, or the largest weight of a focus region
    holding the cell's centre."""
    w = np.ones((grid.ny, grid.nx))
    if not regions:
        return w
    xs = grid.x0 + (np.arange(grid.nx) + 0.5) * grid.cell
    ys = grid.y0 + (np.arange(grid.ny) + 0.5) * grid.cell
    for x0, y0, x1, y1, weight in regions:
        inside = ((ys >= y0) & (ys <= y1))[:, None] & ((xs >= x0) & (xs <= x1))[None, :]
        w[inside] = np.maximum(w[inside], weight)
    return w


def h2(p: F64) -> F64:
    """Binary entropy in bits; ``h2(0) = h2(1) = 0``."""
    p = np.clip(np.asarray(p, dtype=np.float64), 0.0, 1.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = -(p * np.log2(p) + (1.0 - p) * np.log2(1.0 - p))
    return np.nan_to_num(out, nan=0.0)


@dataclass(frozen=True)
class AccuracyModel:
    """The net improvement of map accuracy a view gives a cell (§3.2 choice, Method 5): the share
    of the cell's variance ``v = min(var, sigma_ref^2)`` (an unmapped cell: ``sigma_ref^2``) that
    one view's measurement removes, ``q = v / (v + vm)``, with ``vm`` the stereo's vertical
    variance at the cell's range ``r`` and height below the camera ``dz``:
    ``sigma_z = sigma_d * r * |dz| / (f * B)`` (the depth error ``r^2 sigma_d / (f B)`` along a ray
    that descends by ``|dz| / r``). Far and grazing views of new ground, and views that would
    re-measure a cell no better than it is known, are worth less."""

    sigma_ref_m: float
    disparity_px: float
    focal_baseline_px_m: float  # f * B

    @staticmethod
    def of(cfg: NbvConfig, camera: CameraConfig) -> AccuracyModel | None:
        """The model of ``cfg`` and ``camera``, or None when ``accuracy_sigma_m`` is 0."""
        if cfg.accuracy_sigma_m <= 0.0:
            return None
        return AccuracyModel(cfg.accuracy_sigma_m, cfg.accuracy_disparity_px,
                             camera.focal_px * camera.baseline_m)

    def share(self, rel: F64, sigma_m: F64) -> F64:
        """``q`` per cell: ``rel`` (N, 3) cell points relative to the camera, ``sigma_m`` (N,) the
        cells' elevation sigma on the rating's terrain (an unmapped cell's prior is larger than
        ``sigma_ref``)."""
        r = np.sqrt((np.asarray(rel, dtype=np.float64) ** 2).sum(axis=1))
        s_z = self.disparity_px * r * np.abs(rel[:, 2]) / self.focal_baseline_px_m
        v = np.minimum(np.asarray(sigma_m, dtype=np.float64) ** 2, self.sigma_ref_m**2)
        return np.asarray(v / (v + s_z**2 + 1e-12))


def cell_values(pv: F64, n: NDArray[np.int32], n_max: int, interest: F64 | None,
                planned: F64 | None = None, stereo_return: float = 1.0,
                weight: F64 | None = None) -> tuple[F64, F64]:
    """Per-cell terms of H (Eq 3, bits) and of the expected new cells, given P_V (§3.2, §3.4).

    Two separate factors (§3.4): the interest IF (the map's, decayed by misses; at most 1) is a
    probability term and multiplies P_V inside ``h2(IF P_V / 2)``; ``weight`` (what the task
    needs: a focus region, :func:`focus_weights`, or the Cliff-bot's corridor in team views)
    multiplies the cell's bits. An interest above 1 counts as 1: a weight is no interest. The
    interest and the weight rank views (H) but are no part of the expected new cells: those are
    the same quantity as the obtained count, ``P_V`` of each unmapped cell times
    ``stereo_return`` (the fraction of the cells a view leaves visible that the stereo maps,
    ``VisibilityConfig.stereo_return``).
    ``planned`` (team views, docs/algorithm.md §8.2): the probability that a view other agents
    have already chosen this cycle sees the cell, ``P = 1 - prod_k (1 - P_V,k)``. The cycle's
    views are one measurement of the cell, seen with ``1 - (1 - P)(1 - IF P_V)``; this view's
    bits are what it adds to that, ``share * (h2((P + (1 - P) IF P_V) / 2) - h2(P / 2))`` (the
    marginal gain of a submodular set function of the cycle's views: two views of the same cells
    are worth less than two views of different cells, and nothing where the earlier view surely
    sees), and a cell stays new only with ``1 - P``."""
    p = np.asarray(pv, dtype=np.float64)
    fresh = np.where(np.asarray(n) == 0, p * float(stereo_return), 0.0)
    share = np.clip((n_max - np.asarray(n, dtype=np.float64)) / float(n_max), 0.0, 1.0)
    if interest is not None:
        p = p * np.clip(np.asarray(interest, dtype=np.float64), 0.0, 1.0)
    if weight is not None:
        share = share * np.maximum(np.asarray(weight, dtype=np.float64), 0.0)
    if planned is None:
        return share * h2(p / 2.0), fresh
    before = np.clip(np.asarray(planned, dtype=np.float64), 0.0, 1.0)
    gain = h2((before + (1.0 - before) * np.clip(p, 0.0, 1.0)) / 2.0) - h2(before / 2.0)
    return share * np.maximum(gain, 0.0), fresh * (1.0 - before)


def view_sums(rel: F64, values: F64, yaws: F64, tilts: F64, camera: CameraConfig) -> F64:
    """Sums of per-cell ``values`` (N, V) over each view's field and depth of field (§3.1).

    ``rel`` (N, 3) are the cells' points relative to the camera centre; the views are every
    optical-axis world yaw in ``yaws`` (P,) with every tilt in ``tilts`` (T,). Returns
    (P, T, V). Camera frame as ``geometry.rotation_from_yaw_tilt`` (no roll).
    """
    return run_to_end(view_sums_steps(rel, values, yaws, tilts, camera))


def view_sums_steps(rel: F64, values: F64, yaws: F64, tilts: F64, camera: CameraConfig
                    ) -> Generator[None, None, F64]:
    """:func:`view_sums`, yielding before the set-up (the caller's work before it is a step
    of its own), after it and after each tilt."""
    yield None
    rho = np.hypot(rel[:, 0], rel[:, 1]).astype(np.float32)
    phi = np.arctan2(rel[:, 1], rel[:, 0])
    dz = rel[:, 2].astype(np.float32)
    cos_d = (np.cos(phi)[:, None] * np.cos(yaws)[None, :]
             + np.sin(phi)[:, None] * np.sin(yaws)[None, :]).astype(np.float32)
    sin_d = (np.sin(phi)[:, None] * np.cos(yaws)[None, :]
             - np.cos(phi)[:, None] * np.sin(yaws)[None, :]).astype(np.float32)
    lateral = np.abs(rho[:, None] * sin_d)
    along = rho[:, None] * cos_d
    tan_h = np.float32(math.tan(math.radians(camera.hfov_deg) / 2.0))
    tan_v = np.float32(math.tan(camera.vfov_rad / 2.0))
    vals = np.ascontiguousarray(values.T, dtype=np.float32)
    out = np.empty((yaws.size, tilts.size, values.shape[1]))
    for j, tau in enumerate(tilts):
        yield None
        ct, st = np.float32(math.cos(tau)), np.float32(math.sin(tau))
        zc = along * ct + (dz * st)[:, None]
        yc = along * st - (dz * ct)[:, None]
        ok = ((zc >= camera.min_range_m) & (zc <= camera.max_range_m)
              & (lateral <= zc * tan_h) & (np.abs(yc) <= zc * tan_v))
        # einsum, not matmul: multithreaded BLAS on small products spins on a busy machine
        out[:, j, :] = np.einsum("vn,np->pv", vals, ok.astype(np.float32))
    yield None  # the last tilt is a step of its own, apart from what the caller does next
    return out


@dataclass(frozen=True)
class StationRating:
    """H and expected new cells of every pan/tilt at one camera centre: arrays (P, T)."""

    info_bits: F64
    expected_new_cells: F64
    cells_rated: int


def rate_station(terrain: Terrain, cam_xyz: tuple[float, float, float], yaws: F64, tilts: F64,
                 n: NDArray[np.int32], n_max: int, interest: F64 | None, camera: CameraConfig,
                 cfg: VisibilityConfig, planned: F64 | None = None,
                 accuracy: AccuracyModel | None = None, weight: F64 | None = None) -> StationRating:
    """Rate all pan/tilt views (world yaws x tilts) from one camera centre (§3.1, §3.2);
    ``planned``: other agents' chosen views this cycle, ``weight``: the task's weight of each
    cell's bits (:func:`cell_values`); ``accuracy``: Method 5's accuracy weight
    (:class:`AccuracyModel`)."""
    return run_to_end(rate_station_steps(terrain, cam_xyz, yaws, tilts, n, n_max, interest,
                                         camera, cfg, planned, accuracy, weight))


def rate_station_steps(terrain: Terrain, cam_xyz: tuple[float, float, float], yaws: F64,
                       tilts: F64, n: NDArray[np.int32], n_max: int, interest: F64 | None,
                       camera: CameraConfig, cfg: VisibilityConfig, planned: F64 | None = None,
                       accuracy: AccuracyModel | None = None, weight: F64 | None = None
                       ) -> Generator[None, None, StationRating]:
    """:func:`rate_station` in bounded steps (for the executive's slack jobs)."""
    g = terrain.grid
    reach = horizontal_reach_m(camera)
    x_c = g.x0 + (np.arange(g.nx) + 0.5) * g.cell
    y_c = g.y0 + (np.arange(g.ny) + 0.5) * g.cell
    near = ((x_c[None, :] - cam_xyz[0]) ** 2 + (y_c[:, None] - cam_xyz[1]) ** 2) <= reach**2
    worth = near & (n < n_max)
    if planned is not None:  # a cell an earlier view surely sees adds nothing (``cell_values``)
        worth &= planned < 1.0
    if interest is not None:
        worth &= interest > 0
    iy, ix = np.nonzero(worth)
    if iy.size == 0:
        zero = np.zeros((yaws.size, tilts.size))
        return StationRating(zero, zero.copy(), 0)
    pv = yield from pv_fast_steps(terrain, cam_xyz, iy, ix, cfg)
    bits, new = cell_values(pv, n[iy, ix], n_max, None if interest is None else interest[iy, ix],
                            None if planned is None else planned[iy, ix], cfg.stereo_return,
                            None if weight is None else np.asarray(weight)[iy, ix])
    rel = np.column_stack([x_c[ix] - cam_xyz[0], y_c[iy] - cam_xyz[1],
                           terrain.elev_m[iy, ix] - cam_xyz[2]])
    if accuracy is not None:
        bits = bits * accuracy.share(rel, terrain.sigma_m[iy, ix])
    keep = (bits > 1e-6) | (new > 1e-6)
    sums = yield from view_sums_steps(rel[keep], np.column_stack([bits[keep], new[keep]]), yaws,
                                      tilts, camera)
    return StationRating(sums[..., 0], sums[..., 1], int(iy.size))


def predicted_visibility(emap: MapLike, pose: CameraPose, camera: CameraConfig,
                         cfg: VisibilityConfig) -> F64:
    """P_V of every map cell for one camera pose, zero outside the view (the ``p_visible``
    that ``ElevationMap.merge`` uses to record misses and decay the interest, §3.4, §4)."""
    return run_to_end(predicted_visibility_steps(emap, pose, camera, cfg))


def predicted_visibility_steps(emap: MapLike, pose: CameraPose, camera: CameraConfig,
                               cfg: VisibilityConfig, skip: NDArray[np.bool_] | None = None
                               ) -> Generator[None, None, F64]:
    """:func:`predicted_visibility` in bounded steps (the terrain prior, the field of view,
    then ``pv_fast_steps``), for the perception job. Cells in ``skip`` (the cells the view
    measured, whose P_V a merge does not use) get 0 without being rated; the field of view is
    tested only on the cells within the frustum's horizontal reach of the camera."""
    terrain = terrain_from_map(emap.z, emap.var, emap.grid, cfg)
    yield None
    g = emap.grid
    box = np.ones(g.shape, bool)
    if np.isfinite(pose.t[:2]).all():  # no cell centre beyond the reach is in view
        reach = horizontal_reach_m(camera) + g.cell
        lo = np.floor((pose.t[:2] - reach - (g.x0, g.y0)) / g.cell).astype(int)
        hi = np.floor((pose.t[:2] + reach - (g.x0, g.y0)) / g.cell).astype(int) + 1
        box[:] = False
        box[max(lo[1], 0):max(hi[1], 0), max(lo[0], 0):max(hi[0], 0)] = True
    iy, ix = np.nonzero(box if skip is None else box & ~skip)
    pts = np.column_stack([g.x0 + (ix + 0.5) * g.cell, g.y0 + (iy + 0.5) * g.cell,
                           terrain.elev_m[iy, ix]])
    vis = in_view(pose, camera, pts)
    out = np.zeros(g.shape)
    if vis.any():
        yield None
        cam = (float(pose.t[0]), float(pose.t[1]), float(pose.t[2]))
        out[iy[vis], ix[vis]] = yield from pv_fast_steps(terrain, cam, iy[vis], ix[vis], cfg)
    return out


def motion_cost(poses: F64, current: F64, cfg: NbvConfig) -> F64:
    """Eq 9 between candidate poses (K, 6) and the current pose (6,): x, y, yaw, pan, tilt, lift."""
    d = np.asarray(poses, dtype=np.float64) - np.asarray(current, dtype=np.float64)
    d[:, 2:5] = wrap_angle(d[:, 2:5])
    a = np.array([cfg.a_xy, cfg.a_xy, cfg.a_yaw, cfg.a_pan, cfg.a_tilt, cfg.a_lift])
    return np.sqrt((a * d**2).sum(axis=1))


def localization_sigma(travel_m: F64, sigma_now_m: float, landmark_range_m: F64,
                       cfg: NbvConfig) -> F64:
    """Position sigma after the move (§3.5): drift over ``travel_m`` fused with a fiducial fix
    at ``landmark_range_m`` (inf where no landmark is in view)."""
    odo = np.sqrt(sigma_now_m**2 + (cfg.odo_drift_frac * np.asarray(travel_m)) ** 2)
    rng = np.asarray(landmark_range_m, dtype=np.float64)
    fid = np.where(rng <= cfg.fiducial_range_m, cfg.fiducial_sigma_1m_m * np.maximum(rng, 1.0)**2,
                   np.inf)
    with np.errstate(divide="ignore"):
        return np.asarray(1.0 / np.sqrt(1.0 / np.maximum(odo, 1e-12) ** 2 + 1.0 / fid**2))


def utility(info_bits: F64, motion: F64, sigma_loc_m: F64, cfg: NbvConfig) -> F64:
    """§3.5: ``U = H - w_d d - w_l sigma_loc``."""
    return np.asarray(info_bits) - cfg.w_motion * np.asarray(motion) - cfg.w_loc * np.asarray(
        sigma_loc_m)


def info_n_max(emap: MapLike, cfg: NbvConfig) -> int:
    """The ``n_max`` of Eq 3: ``cfg.info_n_max``, or the map's cap when that is 0."""
    return int(cfg.info_n_max) if cfg.info_n_max > 0 else int(emap.n_max)


def end_reason(step: int, best_info_bits: float | None, mapped_fraction: float,
               cfg: NbvConfig) -> str | None:
    """§3.6: why the mission should stop now, or None to go on."""
    if step >= cfg.max_steps:
        return f"step limit reached ({cfg.max_steps})"
    if mapped_fraction >= cfg.target_mapped_fraction:
        return f"region of interest {100 * mapped_fraction:.1f}% mapped"
    if best_info_bits is not None and best_info_bits < cfg.min_info_bits:
        return f"best view offers {best_info_bits:.1f} bit < {cfg.min_info_bits:.1f}"
    return None
