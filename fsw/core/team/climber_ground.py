"""The ground the Cliff-bot can stand on (docs/algorithm.md §8, "Task execution"): what it can
drive on (:class:`ClimberConfig`), its footprint on the map (the wheels' outline at the heading it
holds, laid in the ground's plane: :func:`footprint_box`, :func:`body_yaw`, :func:`standing_cells`)
and the map's layers the task planner judges its nodes on (:func:`ground_layers`: rocks, hazards
grown by the footprint, footprints whose every cell a sensor measured, the slope under the body).

The planner (:mod:`fsw.core.team.face_planner`) adds the tethers, the ways between nodes and the
search; the mission's looks (``fsw.tasks.cliffbot.head_sight``) and the ground it has stood on
(:mod:`fsw.core.team.contact_ground`) read the footprint from here.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from fsw.core.codec.hazard import known_gradient_mean, relief
from fsw.core.geometry import MapGrid
from fsw.core.team.tether import ZMap
from fsw.framework.params import param

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class ClimberConfig:
    """What the Cliff-bot can drive on, and the planner's lattice."""

    wheel_d_m: float = param(0.12, lo=0.01, hi=2.0, units="m", doc="wheel diameter: the critical length")
    footprint_m: float = param(0.3, lo=0.02, hi=5.0, units="m",
                               doc="radius over which the plane the Cliff-bot stands on is fitted")
    body_half_length_m: float = param(0.3, lo=0.01, hi=5.0, units="m",
                                      doc="its footprint, the wheels' outline: half its length along its heading")
    body_half_width_m: float = param(0.225, lo=0.01, hi=5.0, units="m",
                                     doc="its footprint, the wheels' outline: half its width across its heading")
    rock_disc_m: float = param(0.6, lo=0.05, hi=10.0, units="m", doc="disc of the top-hat that finds rocks")
    max_slope_deg: float = param(87.0, lo=1.0, hi=90.0, units="deg", doc="steeper ground is a hazard")
    free_slope_deg: float = param(25.0, lo=0.0, hi=90.0, units="deg",
                                  doc="up to this slope the wheels hold the Cliff-bot without the tethers")
    node_m: float = param(0.06, lo=0.005, hi=5.0, units="m", doc="planner lattice spacing")


@dataclass(frozen=True)
class Ground:
    """The map's hazard layers at full resolution."""

    rock: NDArray[np.bool_]  # relief above the top-hat threshold
    hazard: NDArray[np.bool_]  # rock, step, rough or too steep, grown by the footprint
    known: NDArray[np.bool_]  # the whole footprint known
    slope_deg: NDArray[np.float32]


def disc(radius_cells: int) -> NDArray[np.bool_]:
    r = max(0, radius_cells)
    yy, xx = np.mgrid[-r:r + 1, -r:r + 1]
    return np.asarray(xx * xx + yy * yy <= r * r)


def standing_cells(grid: MapGrid, xy: F64, cfg: ClimberConfig, anchors: F64 | None = None,
                   body: tuple[float, float, float] | None = None) -> NDArray[np.bool_]:
    """The cells where the Cliff-bot stands at ``xy``: its footprint (:func:`footprint_box`, level,
    at the heading it holds there, :func:`body_yaw`) round ``xy`` and round the lattice node
    nearest it (the node it stands at), that node, and with ``body`` (its heading, half length
    and half width) the cells its body's outline covers, a cell partly under it included (the
    body rests on that ground and no camera sees under it). The level footprint holds every
    tilted one of the same heading."""
    out = np.zeros(grid.shape, bool)
    iy, ix, inside = grid.cell_index(np.array([xy[0]]), np.array([xy[1]]))
    if body is not None:
        X, Y = grid.centers()
        yaw, half_len, half_wid = body
        dx, dy = X - xy[0], Y - xy[1]
        along = dx * math.cos(yaw) + dy * math.sin(yaw)
        across = -dx * math.sin(yaw) + dy * math.cos(yaw)
        out |= (np.abs(along) <= half_len + 0.5 * grid.cell) & (np.abs(across) <= half_wid + 0.5 * grid.cell)
    if not bool(inside[0]):
        return out
    stride = max(1, int(round(cfg.node_m / grid.cell)))
    # the lattice's rows and columns are stride // 2 + k * stride (plan_targets' node_of)
    rows, cols = np.arange(stride // 2, grid.ny, stride), np.arange(stride // 2, grid.nx, stride)
    ky = min(len(rows) - 1, max(0, int(round((int(iy[0]) - int(rows[0])) / stride))))
    kx = min(len(cols) - 1, max(0, int(round((int(ix[0]) - int(cols[0])) / stride))))
    hl, hw = cfg.body_half_length_m / grid.cell, cfg.body_half_width_m / grid.cell
    for r, c in ((int(iy[0]), int(ix[0])), (int(rows[ky]), int(cols[kx]))):
        centre = np.array([grid.x0 + (c + 0.5) * grid.cell, grid.y0 + (r + 0.5) * grid.cell])
        ybin = YAW_BINS if anchors is None else int(yaw_bins(anchors, centre[:1], centre[1:])[0])
        foot = footprint_box(hl, hw, FOOT_COS_LEVELS, 0, ybin)
        k = (foot.shape[0] - 1) // 2
        dy, dx = np.nonzero(foot)
        y, x = r + dy - k, c + dx - k
        ok = (y >= 0) & (y < grid.ny) & (x >= 0) & (x < grid.nx)
        out[y[ok], x[ok]] = True
    return out


FOOT_COS_LEVELS = 4  # the footprint's cos(slope) rounded up to quarters (a larger footprint: the safe side)
FOOT_DIP_BINS = 8  # dip directions over 180 deg; each bin's footprint is the union over the bin
YAW_BINS = 64  # headings over 180 deg (the box is the same end for end); each bin's the union over the bin
FOOT_GATHER = 1 << 20  # cells x footprint offsets gathered at once (bounds the memory of a footprint's test)


def body_yaw(anchors: F64, x: F64, y: F64) -> F64:
    """The heading (rad) the Cliff-bot holds at each place ``(x, y)``: away from the anchors, down
    the bisector of its tethers' directions in plan (each tether lies in the vertical plane through
    its anchor and the body; the bench hangs the body down the bisector of the tethers' pulls)."""
    a = np.asarray(anchors, float)
    sx, sy = np.zeros(np.shape(x)), np.zeros(np.shape(x))
    for k in range(2):
        dx, dy = a[k, 0] - np.asarray(x, float), a[k, 1] - np.asarray(y, float)
        d = np.maximum(np.hypot(dx, dy), 1e-9)
        sx, sy = sx + dx / d, sy + dy / d
    return np.asarray(np.arctan2(-sy, -sx), np.float64)


def yaw_bins(anchors: F64, x: F64, y: F64) -> NDArray[np.intp]:
    """The heading bin (of :data:`YAW_BINS` over 180 deg) of :func:`body_yaw` at each place."""
    yaw = np.mod(body_yaw(anchors, x, y), math.pi)
    return np.minimum((yaw / (math.pi / YAW_BINS)).astype(np.intp), YAW_BINS - 1)


@functools.lru_cache(maxsize=4096)
def footprint_box(half_len: float, half_wid: float, cos_level: int, dip_bin: int, yaw_bin: int
                  ) -> NDArray[np.bool_]:
    """The Cliff-bot's footprint, in cells (``half_len``, ``half_wid``: its wheels' outline, the
    body's box, in cells): the cells whose centre lies within half a cell of the box laid in a plane
    whose slope has cos ``cos_level / FOOT_COS_LEVELS`` (dip in bin ``dip_bin`` of
    ``FOOT_DIP_BINS`` over 180 deg), its long axis over the heading bin ``yaw_bin`` of
    :data:`YAW_BINS` in plan, seen from above; the union over the bins' directions.
    ``cos_level == FOOT_COS_LEVELS``: level ground; ``yaw_bin == YAW_BINS``: every heading."""
    r = int(math.ceil(math.hypot(half_len, half_wid) + 0.5))
    yy, xx = np.mgrid[-r:r + 1, -r:r + 1].astype(np.float64)
    tilt = 0.0 if cos_level >= FOOT_COS_LEVELS else math.tan(math.acos(max(cos_level, 1) / FOOT_COS_LEVELS))
    dw, yw = math.pi / FOOT_DIP_BINS, math.pi / YAW_BINS
    dips = [0.0] if tilt == 0.0 else list((dip_bin + 0.5) * dw + np.linspace(-0.5, 0.5, 5) * dw)
    yaws = (np.arange(YAW_BINS) * yw if yaw_bin >= YAW_BINS
            else (yaw_bin + 0.5) * yw + np.linspace(-0.5, 0.5, 5) * yw)
    out = np.zeros(xx.shape, bool)
    for phi in dips:
        n = np.array([-tilt * math.cos(phi), -tilt * math.sin(phi), 1.0])
        n /= np.linalg.norm(n)
        dz = tilt * (xx * math.cos(phi) + yy * math.sin(phi))  # the plane's height at each offset
        for yaw in yaws:
            a = np.array([math.cos(yaw), math.sin(yaw), tilt * math.cos(yaw - phi)])
            a /= np.linalg.norm(a)  # the long axis in the plane, over the heading in plan
            b = np.cross(n, a)
            along = xx * a[0] + yy * a[1] + dz * a[2]
            across = xx * b[0] + yy * b[1] + dz * b[2]
            out |= (np.abs(along) <= half_len + 0.5) & (np.abs(across) <= half_wid + 0.5)
    out[r, r] = True
    return out


def _cos_level(grad: NDArray[np.float64]) -> NDArray[np.intp]:
    """cos(slope) of a gradient's norm in quarters, rounded up."""
    cos = 1.0 / np.sqrt(1.0 + grad * grad)
    return np.minimum(np.ceil(cos * FOOT_COS_LEVELS - 1e-9), FOOT_COS_LEVELS).astype(np.intp)


def slope_levels(zs: NDArray[np.float64], cell: float
                 ) -> tuple[NDArray[np.float64], NDArray[np.intp], NDArray[np.intp]]:
    """Each cell's slope from the known cells round it (3 x 3): the gradient's norm (inf with
    too few known cells), its cos in quarters rounded up (:func:`_cos_level`) and the dip's bin
    of ``FOOT_DIP_BINS`` over 180 deg."""
    mx, my, n = known_gradient_mean(zs, cell, 3)
    local = np.where(n >= 5.0 / 9.0 - 1e-9, np.hypot(mx, my), np.inf)
    level = _cos_level(np.where(np.isfinite(local), local, 0.0))
    dip = np.mod(np.arctan2(my, mx), math.pi)
    dbin = np.minimum((dip / (math.pi / FOOT_DIP_BINS)).astype(np.intp), FOOT_DIP_BINS - 1)
    return local, level, dbin


def map_yaw_bins(grid: MapGrid, anchors: F64 | None) -> NDArray[np.intp]:
    """Each cell's heading bin (:func:`yaw_bins`); ``YAW_BINS`` (every heading) without anchors."""
    if anchors is None:
        return np.full(grid.shape, YAW_BINS, np.intp)
    X, Y = grid.centers()
    return yaw_bins(anchors, X, Y)


def over_footprints(ty: NDArray[np.intp], tx: NDArray[np.intp], keys: NDArray[np.intp],
                    mask: Callable[[int], NDArray[np.bool_]], shape: tuple[int, int], r: int,
                    judge: Callable[[NDArray[np.intp], NDArray[np.intp]], None]) -> None:
    """Each cell ``(ty, tx)``'s own footprint (``mask(key)`` of its ``keys``, radius ``r`` or less),
    gathered at that cell only: ``judge(sel, idx)`` is called with the cells' indices into ``ty``
    and, for each, the flat indices of its footprint's cells in the map padded by ``r`` on every
    side (a whole-map filter per footprint would judge every cell of the map with every one)."""
    width = shape[1] + 2 * r
    at = (ty + r) * width + (tx + r)
    for key in np.unique(keys):
        m = mask(int(key))
        k = (m.shape[0] - 1) // 2
        dy, dx = np.nonzero(m)
        offsets = (dy - k) * width + (dx - k)
        sel = np.flatnonzero(keys == key)
        chunk = max(1, FOOT_GATHER // len(offsets))
        for j in range(0, len(sel), chunk):
            cells = sel[j:j + chunk]
            judge(cells, at[cells, None] + offsets)


def footprint_known(z_sensed: ZMap, grid: MapGrid, cfg: ClimberConfig, anchors: F64 | None = None
                    ) -> NDArray[np.bool_]:
    """The cells whose footprint is known: the Cliff-bot's footprint (:func:`footprint_box`, its
    wheels' outline at the heading it holds there, :func:`body_yaw`; every heading without
    ``anchors``) laid in the ground's own plane, which from above is shortened along the dip by
    the slope's cos (at 77 deg a 0.6 m long body spans 0.14 m of the map along the dip, where
    the level box would need 2.7 m of face along the slope), all on cells with a height from a
    sensor (``z_sensed``, NaN elsewhere). The slope and dip are a cell's (from the known cells
    round it, 3 x 3); the cos is rounded up to quarters and the dip's and heading's directions
    binned, each bin's footprint the union over its directions, and a tilted footprint that holds
    a flatter cell (a lip, a ledge) gives way to the level one (the safe side of each)."""
    zs = np.asarray(z_sensed, np.float64)
    sensed = np.isfinite(zs)
    out = np.zeros(sensed.shape, bool)
    if not sensed.any():
        return out
    hl, hw = cfg.body_half_length_m / grid.cell, cfg.body_half_width_m / grid.cell
    r = int(math.ceil(math.hypot(hl, hw) + 0.5))
    local, level, dbin = slope_levels(zs, grid.cell)
    ybin = map_yaw_bins(grid, anchors)
    ty, tx = np.nonzero(sensed)
    yb = ybin[ty, tx]
    flat_sensed = np.pad(sensed, r, constant_values=False).ravel()  # off the map is no ground
    flat_local = np.pad(local, r, constant_values=np.inf).ravel()
    level_known = ~footprint_holds(~sensed, sensed, ybin, cfg, grid, off_map=True)[ty, tx]
    lv = level[ty, tx]
    got = level_known.copy()
    tilted = np.flatnonzero(lv < FOOT_COS_LEVELS)
    keys = (lv[tilted] * FOOT_DIP_BINS + dbin[ty[tilted], tx[tilted]]) * (YAW_BINS + 1) + yb[tilted]

    def tilted_judge(cells: NDArray[np.intp], idx: NDArray[np.intp]) -> None:
        at = tilted[cells]
        # the footprint holds no flatter ground (a lip, a ledge): else the level one, the safe side
        least = flat_local[idx].min(axis=1)
        fits = _cos_level(np.where(np.isfinite(least), least, 0.0)) <= lv[at]
        got[at] = np.where(fits, flat_sensed[idx].all(axis=1), level_known[at])

    def tilted_mask(key: int) -> NDArray[np.bool_]:
        rest, y = divmod(key, YAW_BINS + 1)
        c, d = divmod(rest, FOOT_DIP_BINS)
        return footprint_box(hl, hw, c, d, y)

    over_footprints(ty[tilted], tx[tilted], keys, tilted_mask, sensed.shape, r, tilted_judge)
    out[ty, tx] = got
    return out


def footprint_holds(raw: NDArray[np.bool_], at: NDArray[np.bool_], ybin: NDArray[np.intp], cfg: ClimberConfig,
                    grid: MapGrid, off_map: bool = False) -> NDArray[np.bool_]:
    """The cells of ``at`` whose level footprint (:func:`footprint_box`, at each cell's heading bin
    ``ybin``) holds a cell of ``raw`` (``off_map``: whether ground off the map counts as one). Only
    the cells within the footprint's reach of one are gathered (:func:`over_footprints`)."""
    hl, hw = cfg.body_half_length_m / grid.cell, cfg.body_half_width_m / grid.cell
    r = int(math.ceil(math.hypot(hl, hw) + 0.5))
    out = np.zeros(raw.shape, bool)
    reach = ndimage.maximum_filter(raw, size=2 * r + 1, mode="constant", cval=off_map)
    ty, tx = np.nonzero(at & reach)
    if not len(ty):
        return out
    flat_raw = np.pad(raw, r, constant_values=off_map).ravel()
    hit = np.zeros(len(ty), bool)

    def judge(cells: NDArray[np.intp], idx: NDArray[np.intp]) -> None:
        hit[cells] = flat_raw[idx].any(axis=1)

    over_footprints(ty, tx, ybin[ty, tx], lambda k: footprint_box(hl, hw, FOOT_COS_LEVELS, 0, k), raw.shape, r,
                    judge)
    out[ty, tx] = hit
    return out


def footprint_slope(z: F64, cell_m: float, k: int) -> F64:
    """The ground's slope (deg) over a ``k`` x ``k`` footprint round each cell (what the
    Cliff-bot's body stands on): the mean of the gradients inside it that known cells give
    (central differences; none beside an unknown cell), 90 (too steep) where it holds none.
    Unknown cells do not enter it (as in :func:`slope_levels`): filled with any height, a hole
    in the map would read as a cliff and the known ground round it as too steep to stand on."""
    mx, my, w = known_gradient_mean(z, cell_m, k)
    return np.where(w > 1e-9, np.degrees(np.arctan(np.hypot(mx, my))), 90.0)


def ground_layers(z: ZMap, grid: MapGrid, cfg: ClimberConfig, unseen: NDArray[np.bool_] | None = None,
                  anchors: F64 | None = None) -> Ground:
    """Rocks, hazards, known footprints and slope of every cell; the footprint is the Cliff-bot's
    wheels' outline at the heading it holds at each cell (:func:`footprint_box`,
    :func:`body_yaw` from ``anchors``; every heading without them). ``unseen``: cells with a
    height that no sensor measured (the plane under the Cliff-bot's body carried on beyond where
    its wheels stand): their heights shape the slope and the tethers, but a footprint that holds
    one is not known."""
    zf = np.asarray(z, np.float64)
    known = np.isfinite(zf)
    k = 2 * int(round(cfg.footprint_m / grid.cell)) + 1
    slope = footprint_slope(zf, grid.cell, k)
    # Relief above a flat opening, measured across the ground (times cos slope): on a steep
    # face a bump's height in z is its height off the face over cos(slope). The opening takes
    # the discs centred on unknown cells too (their known cells): with only the discs centred on
    # known ground, a cell at the edge of the known ground above a drop (the plateau's last
    # decimetres before a lip, the ground beyond them not yet seen) sits on no disc but those
    # reaching down the drop and reads as a rock of the drop's height; on a map that knows every
    # cell (the truth) it is the codec's relief (§6).
    tophat = np.nan_to_num(relief(zf, grid.cell, cfg.rock_disc_m, unknown_centres=True), nan=0.0)
    rock = known & (tophat * np.cos(np.radians(slope)) >= cfg.wheel_d_m)
    steep = slope > cfg.max_slope_deg
    raw = rock | steep
    hazard = footprint_holds(raw, known, map_yaw_bins(grid, anchors), cfg, grid)  # grown by the footprint
    sensed = known if unseen is None or unseen.shape != known.shape else known & ~unseen
    known_foot = footprint_known(np.where(sensed, zf, np.nan), grid, cfg, anchors)
    return Ground(rock, hazard, known_foot, slope.astype(np.float32))
