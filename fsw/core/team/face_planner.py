"""The Cliff-bot's task planner: paths to science targets on the face, under tether limits
(docs/algorithm.md §8, "Task execution").

The planner works on a 2.5D map (NaN: unknown) and the anchors' positions; the same code
plans on the map the Cliff-bot received (the flight) and on the truth (the bench's
brute-force check of what is reachable at all).

1. **Nodes.** Map cells every ``node_m``. A node is *usable* when the ground under the
   Cliff-bot's footprint (its wheels' outline at the heading it holds there,
   :func:`footprint_box`) is known, is not a hazard, and the tethers hold it there:
   - *hazard*: a rock (white top-hat relief over a ``rock_disc_m`` disc ``>= wheel_d_m``: a
     flat opening keeps every monotone profile, so the face, the lip and the foot are not
     rocks, while a bump narrower than the disc is), or ground steeper than
     ``max_slope_deg`` (a wall); hazards are grown by the footprint. Ledges and the
     lip are not hazards: the tethers carry the Cliff-bot over them;
   - *tethers*: both taut paths (:mod:`fsw.core.team.tether`) within the spool, over known
     ground, with no contact on a rock; where the plane the Cliff-bot stands on (the statics'
     normal, :func:`fsw.core.team.standing_plane.surface_normal`) is steeper than ``free_slope_deg`` the
     equilibrium must hold with both tensions in ``[T_min, T_max]`` and the wheels on the
     face (below it, the wheels hold the Cliff-bot and the winches only keep the tethers
     taut); with :class:`Margins` ``errors``, the tethers must also hold it where the lengths'
     errors may put it: settled at the node's lengths off by each error the planner tolerates
     (the winches' own, the map's height error shared by both tethers), the statics re-solved
     there (:func:`fsw.core.team.held_tension.held_reason`; ``tension not held`` where that
     settling, bounded, ends undecided).
2. **Edges.** Usable 8-neighbours, weighted by their 3-D distance; with :class:`Margins`, an
   edge within ``clearance_m`` of a hazard cell costs more (up to ``1 + weight`` times its
   length), so a path keeps the clearance the body's tracking and navigation errors need
   where the ground leaves room, while what is reachable stays what the wheels' limits allow
   (the truth's verdict). A plan's lengths are its paths' 3-D lengths, not their costs.
3. **Search.** A* from the Cliff-bot's node to each target, nodes judged as the search
   reaches them (:func:`plan_targets` says why not a whole-lattice graph search). A target
   that is not reached gets the reason of its own node (``unknown ground``, ``hazard``,
   ``out of tether reach``, ``slack``,
   ``over-tension``, ``tension not held``, ``off the face``, ``tether over a rock``, ``tether
   over unknown ground``, ``off the map``) or, when its node is usable, ``no safe path``. The start is
   judged like any node, except with ``start_usable`` (the Cliff-bot stands there, held by
   its tethers, and plans its way out of it); ``blocked`` edges (pairs of places) are not
   taken (the mission's check of the way between waypoints, ``fsw.tasks.cliffbot_mission``).
4. **The way between nodes** (:func:`way_reason`). The winches move both tether lengths
   straight from one node's to the next's and the body rests where the statics put it, not on
   the line between the nodes; every place it passes is judged like a node, and it must end
   at the next node: the same two lengths can hold it elsewhere (on the face above a ledge
   whose lengths they are). The mission checks each way it drives on its map; the truth's
   brute force (``hil_sim.team.team_eval``) checks the edges of its paths on the true ground
   with the same function and the same limits.
"""

from __future__ import annotations

import functools
import heapq
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from fsw.core.codec.hazard import relief
from fsw.core.geometry import MapGrid
from fsw.core.team.held_tension import NOT_HELD, LengthErrors, held_at, held_reason, length_covariance, length_offsets
from fsw.core.team.tether import (
    TetherConfig,
    TetherState,
    ZMap,
    attach_point,
    clearance_over,
    tether_state,
    tether_states,
)
from fsw.core.team.tether_settle import settle
from fsw.framework.params import param

F64 = NDArray[np.float64]

USABLE = "usable"
WAY_STEP_M = 0.03  # the way between nodes is followed in steps of at most this much tether
ROCK_SUB_STEPS = 8  # a way's step where a tether passes over a rock is judged again at this many sub-steps
OFF_THE_WAY = "the lengths hold it elsewhere"
Settle = Callable[[ZMap, MapGrid, F64, tuple[float, float], F64, TetherConfig], tuple[F64, TetherState] | None]
"""Where the lengths put the body (:func:`fsw.core.team.tether_settle.settle`'s signature): what
:func:`way_reason` follows a way with."""
REASONS = ("off the map", "unknown ground", "hazard", "out of tether reach", "tether over unknown ground",
           "tether over a rock", "slack", "over-tension", "off the face", "degenerate", NOT_HELD)


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
class Margins:
    """A soft margin: the extra cost of passing near a hazard; and, with ``errors``, the hard
    check that the tethers hold the body where the lengths' errors may put it
    (:mod:`fsw.core.team.held_tension`)."""

    clearance_m: float = 0.0  # within this of a hazard cell an edge costs more
    weight: float = 4.0  # an edge's cost at its worst: (1 + weight) x its length
    errors: LengthErrors = LengthErrors()  # what parts the body's lengths from the map's (none: hard limits only)


def place_covariance(z: ZMap, grid: MapGrid, anchors: F64, xy: F64, tcfg: TetherConfig, ccfg: ClimberConfig,
                     errors: LengthErrors, est_cov: F64 | None = None) -> tuple[F64, TetherState] | None:
    """Where the body may be when the winches hold the lengths of place ``xy``: the lengths'
    covariance (:func:`fsw.core.team.held_tension.length_covariance`: the winches' own errors,
    the map's height error shared by both tethers) carried to the place through the lengths'
    Jacobian, ``J^+ S J^+T``, plus the estimate's covariance ``est_cov``. Returns
    ``(covariance 2x2, state at xy)``; None where the ground round it is not known (central
    differences over one map cell)."""
    h = grid.cell
    pts = np.asarray(xy, float)[None, :] + np.array([[0, 0], [h, 0], [-h, 0], [0, h], [0, -h]], float)
    ss = tether_states(z, grid, anchors, pts, tcfg, ccfg.footprint_m)
    if any(s is None for s in ss):
        return None
    st = [s for s in ss if s is not None]
    lengths = np.array([s.lengths_m for s in st])
    jl = np.column_stack([lengths[1] - lengths[2], lengths[3] - lengths[4]]) / (2 * h)  # dL_i/dx_k
    if not np.isfinite(jl).all():
        return None
    jp = np.linalg.pinv(jl)
    cov = jp @ length_covariance(st[0], errors) @ jp.T
    return cov + (np.zeros((2, 2)) if est_cov is None else np.asarray(est_cov, float)), st[0]


@dataclass(frozen=True)
class Ground:
    """The map's hazard layers at full resolution."""

    rock: NDArray[np.bool_]  # relief above the top-hat threshold
    hazard: NDArray[np.bool_]  # rock, step, rough or too steep, grown by the footprint
    known: NDArray[np.bool_]  # the whole footprint known
    slope_deg: NDArray[np.float32]


@dataclass(frozen=True)
class Plan:
    """Paths from the start to each target, or the reason a target is not reachable."""

    paths: tuple[F64 | None, ...]  # (K, 2) xy waypoints from the start, per target
    lengths_m: tuple[float, ...]  # 3-D path length (inf when unreachable)
    reasons: tuple[str, ...]  # "" for a reached target
    start_reason: str  # "" when the start is usable


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


def known_gradient_mean(z: F64, cell_m: float, k: int) -> tuple[F64, F64, F64]:
    """The mean height gradient (``mx``, ``my``, per metre) over a ``k`` x ``k`` window round
    each cell, of the central differences known cells give (none beside an unknown cell), and
    the share ``n`` of the window that gave one (the means are 0 where it is 0)."""
    gy, gx = np.gradient(z, cell_m)
    ok = np.isfinite(gx) & np.isfinite(gy)
    n = ndimage.uniform_filter(ok.astype(np.float64), k)
    mx = ndimage.uniform_filter(np.where(ok, gx, 0.0), k) / np.maximum(n, 1e-9)
    my = ndimage.uniform_filter(np.where(ok, gy, 0.0), k) / np.maximum(n, 1e-9)
    return mx, my, n


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
    # face a bump's height in z is its height off the face over cos(slope).
    tophat = np.nan_to_num(relief(zf, grid.cell, cfg.rock_disc_m), nan=0.0)  # the codec's relief (§6)
    rock = known & (tophat * np.cos(np.radians(slope)) >= cfg.wheel_d_m)
    steep = slope > cfg.max_slope_deg
    raw = rock | steep
    hazard = footprint_holds(raw, known, map_yaw_bins(grid, anchors), cfg, grid)  # grown by the footprint
    sensed = known if unseen is None or unseen.shape != known.shape else known & ~unseen
    known_foot = footprint_known(np.where(sensed, zf, np.nan), grid, cfg, anchors)
    return Ground(rock, hazard, known_foot, slope.astype(np.float32))


def node_reasons(z: ZMap, grid: MapGrid, anchors: F64, tcfg: TetherConfig, ccfg: ClimberConfig,
                 ground: Ground | None = None) -> tuple[NDArray[np.intp], NDArray[np.intp], list[str], Ground]:
    """The lattice (rows and columns of its nodes in the map) and each node's verdict."""
    g = ground if ground is not None else ground_layers(z, grid, ccfg, anchors=anchors)
    stride = max(1, int(round(ccfg.node_m / grid.cell)))
    rows = np.arange(stride // 2, grid.ny, stride)
    cols = np.arange(stride // 2, grid.nx, stride)
    rr, cc = np.meshgrid(rows, cols, indexing="ij")
    iy, ix = rr.ravel(), cc.ravel()
    # Every node that needs its tethers judged, in one batch (the same states one at a time would give).
    todo = np.flatnonzero(g.known[iy, ix] & ~g.hazard[iy, ix])
    xy = np.column_stack([grid.x0 + (ix[todo] + 0.5) * grid.cell, grid.y0 + (iy[todo] + 0.5) * grid.cell])
    states = dict(zip(todo.tolist(), tether_states(z, grid, anchors, xy, tcfg, ccfg.footprint_m), strict=True))
    reasons = ["unknown ground" if not g.known[y, x] else "hazard" if k not in states
               else _tether_verdict(states[k], grid, tcfg, ccfg, g)
               for k, (y, x) in enumerate(zip(iy, ix, strict=True))]
    return rows, cols, reasons, g


def _verdict(z: ZMap, grid: MapGrid, anchors: F64, tcfg: TetherConfig, ccfg: ClimberConfig,
             g: Ground, iy: int, ix: int) -> str:
    if not g.known[iy, ix]:
        return "unknown ground"
    if g.hazard[iy, ix]:
        return "hazard"
    xy = np.array([grid.x0 + (ix + 0.5) * grid.cell, grid.y0 + (iy + 0.5) * grid.cell])
    return _tether_verdict(tether_state(z, grid, anchors, xy, tcfg, ccfg.footprint_m), grid, tcfg, ccfg, g)


def _tether_verdict(st: TetherState | None, grid: MapGrid, tcfg: TetherConfig, ccfg: ClimberConfig,
                    g: Ground) -> str:
    """A known, hazard-free node's verdict from the tethers and statics with the Cliff-bot there."""
    if st is None:
        return "unknown ground"
    if max(st.lengths_m) > tcfg.spool_m:
        return "out of tether reach"
    if any(p.unknown for p in st.paths):
        return "tether over unknown ground"
    if _contact_on_rock(st, grid, g):
        return "tether over a rock"
    if st.statics.tilt_deg > ccfg.free_slope_deg and not st.statics.ok:
        return st.statics.reason
    return USABLE


def node_held_reason(z: ZMap, grid: MapGrid, anchors: F64, xy: F64, tcfg: TetherConfig, ccfg: ClimberConfig,
                     errors: LengthErrors) -> str:
    """Why the tethers may not hold the body at the usable node ``xy`` when its lengths are off
    by what ``errors`` allows (``""``: they hold it, or the ground there is no steeper than
    ``free_slope_deg`` and the wheels hold it; :func:`fsw.core.team.held_tension.held_reason`).
    The planner's check of a node; the truth's judge (``hil_sim.team.team_eval``) applies the
    same one with the winches' tolerance."""
    st = tether_state(z, grid, anchors, np.asarray(xy, float), tcfg, ccfg.footprint_m)
    if st is None or st.statics.tilt_deg <= ccfg.free_slope_deg:
        return ""
    return held_reason(z, grid, anchors, np.asarray(xy, float), st, tcfg, ccfg.free_slope_deg, errors)


def _contact_on_rock(st: TetherState, grid: MapGrid, g: Ground) -> bool:
    """Whether a tether of ``st`` touches the ground on one of the map's rocks."""
    for p in st.paths:
        if len(p.contacts):
            cy, cx, inside = grid.cell_index(p.contacts[:, 0], p.contacts[:, 1])
            if (inside & g.rock[np.clip(cy, 0, grid.ny - 1), np.clip(cx, 0, grid.nx - 1)]).any():
                return True
    return False


def _over_rock(z: ZMap, grid: MapGrid, anchors: F64, xy: F64, tcfg: TetherConfig, ccfg: ClimberConfig,
               near: NDArray[np.bool_]) -> bool:
    """Whether a tether, with the body at ``xy``, passes over a cell of ``near`` (the map's
    rocks grown by a cell)."""
    bot = attach_point(z, grid, np.asarray(xy, float), tcfg, ccfg.footprint_m)
    return bot is not None and any(math.isfinite(clearance_over(z, grid, an, bot, tcfg, near)) for an in anchors)


def _swept_rock(z: ZMap, grid: MapGrid, anchors: F64, la: F64, lb: F64, f0: float, df: float, xy: F64,
                tcfg: TetherConfig, ccfg: ClimberConfig, g: Ground, settle_at: Settle) -> str:
    """``"tether over a rock"`` where, between the way's steps at ``f0`` (the body at ``xy``)
    and ``f0 + df``, a tether touches a rock at one of :data:`ROCK_SUB_STEPS` sub-steps: a
    tether sweeps over a rock of a cell or two between two steps 3 cm of tether apart."""
    for j in range(1, ROCK_SUB_STEPS):
        lengths = la + (f0 + df * j / ROCK_SUB_STEPS) * (lb - la)
        got = settle_at(z, grid, anchors, (float(lengths[0]), float(lengths[1])), xy, tcfg)
        if got is None:
            return "slack"
        xy = got[0]
        if _contact_on_rock(got[1], grid, g):
            return "tether over a rock"
    return ""


def way_reason(z: ZMap, grid: MapGrid, anchors: F64, a: F64, b: F64, tcfg: TetherConfig, ccfg: ClimberConfig,
               g: Ground, step_m: float = WAY_STEP_M, errors: LengthErrors | None = None,
               settle_at: Settle = settle) -> str:
    """Why the body cannot go from node ``a`` to node ``b`` (``""``: it can; module docstring,
    4): both lengths moved straight from ``a``'s to ``b``'s in steps of at most ``step_m`` of
    tether, the body settled at each (``settle``, from the last place) and judged there like a
    node (unknown ground, hazard, the tethers and the statics: :func:`_tether_verdict`), ending
    within a lattice spacing of ``b`` (else :data:`OFF_THE_WAY`). With ``errors``, where the
    statics hold the body (steeper than ``free_slope_deg``) the tethers must also hold it at the
    lengths off by each of the errors' offsets (:func:`fsw.core.team.held_tension.length_offsets`,
    each moving from ``a``'s offset to ``b``'s along the way; :func:`fsw.core.team.held_tension.held_at`).
    A step at either end of which a tether passes over a rock or a cell next to one is judged again at
    :data:`ROCK_SUB_STEPS` sub-steps (:func:`_swept_rock`): no tether may touch the rock between them.
    ``settle_at``: :func:`fsw.core.team.tether_settle.settle` or one that gives its answers (the truth's
    brute force keeps them, ``hil_sim.team.team_eval``). Directed: the way back may differ."""
    sa = tether_state(z, grid, anchors, np.asarray(a, float), tcfg, ccfg.footprint_m)
    sb = tether_state(z, grid, anchors, np.asarray(b, float), tcfg, ccfg.footprint_m)
    if sa is None or sb is None:
        return "unknown ground"
    la, lb = np.asarray(sa.lengths_m), np.asarray(sb.lengths_m)
    n = max(2, int(math.ceil(float(np.max(np.abs(lb - la))) / step_m)))
    xy = np.asarray(a, float)
    held = errors is not None and errors.any
    if errors is not None and held:
        off_a = length_offsets(length_covariance(sa, errors), errors.z)
        off_b = length_offsets(length_covariance(sb, errors), errors.z)
    rocky = bool(g.rock.any())
    near = ndimage.binary_dilation(g.rock, structure=np.ones((3, 3), bool)) if rocky else g.rock
    over = rocky and _over_rock(z, grid, anchors, xy, tcfg, ccfg, near)
    for f in np.arange(1, n + 1) / n:
        lengths = la + f * (lb - la)
        last = xy
        got = settle_at(z, grid, anchors, (float(lengths[0]), float(lengths[1])), xy, tcfg)
        if got is None:
            return "slack"
        xy = got[0]
        iy, ix, inside = grid.cell_index(xy[:1], xy[1:])
        if not inside[0]:
            return "off the map"
        if not g.known[int(iy[0]), int(ix[0])]:
            return "unknown ground"
        if g.hazard[int(iy[0]), int(ix[0])]:
            return "hazard"
        why = _tether_verdict(got[1], grid, tcfg, ccfg, g)
        if why != USABLE:
            return why
        was, over = over, rocky and _over_rock(z, grid, anchors, xy, tcfg, ccfg, near)
        if was or over:
            why = _swept_rock(z, grid, anchors, la, lb, float(f) - 1.0 / n, 1.0 / n, last, tcfg, ccfg, g, settle_at)
            if why:
                return why
        if held and got[1].statics.tilt_deg > ccfg.free_slope_deg:
            why = held_at(z, grid, anchors, xy, got[1], (1.0 - f) * off_a + f * off_b, tcfg, ccfg.free_slope_deg)
            if why:
                return why
    if float(np.hypot(*(xy - np.asarray(b, float)))) > ccfg.node_m:
        return OFF_THE_WAY
    return ""


def plan_targets(z: ZMap, grid: MapGrid, anchors: F64, start_xy: F64, targets_xy: F64,
                 tcfg: TetherConfig, ccfg: ClimberConfig, margins: Margins | None = None,
                 start_usable: bool = False, blocked: Sequence[tuple[F64, F64]] = (),
                 unseen: NDArray[np.bool_] | None = None, ground: Ground | None = None,
                 verdicts: dict[int, str] | None = None) -> Plan:
    """Shortest usable paths from ``start_xy`` to each target (module docstring); ``unseen``
    as for :func:`ground_layers` (no node's footprint, nor a way's place, holds such a cell).
    ``ground``: the layers the nodes are judged on (default ``ground_layers(z, grid, ccfg,
    unseen, anchors)``); the mission's legs pass the layers their ways are judged on
    (``fsw.tasks.cliffbot.legs.Route``), since a way ends at its node's place and is judged
    there: a node that fails on them is the end of no way, and a search through it only finds
    edges to cut. ``verdicts``: the nodes' verdicts already worked out on the same map, ground
    and margins (lattice index -> its verdict, :data:`USABLE` or the reason), read and filled; a caller that plans
    again on them (a leg's edges cut, its approach) judges each node once.

    A* per target over the 8-connected lattice, with the 3-D straight distance as its
    (admissible) heuristic; a node's verdict is worked out when the search first reaches it
    and kept for the next target. Evaluating only the nodes a search reaches is why this is
    not one ``scipy.sparse.csgraph`` call over the whole lattice: a verdict (two tether paths
    and the statics) costs far more than a graph step, and most of the lattice is never
    needed."""
    zf = np.asarray(z, np.float64)
    g = ground if ground is not None else ground_layers(zf, grid, ccfg, unseen, anchors)
    stride = max(1, int(round(ccfg.node_m / grid.cell)))
    rows = np.arange(stride // 2, grid.ny, stride)
    cols = np.arange(stride // 2, grid.nx, stride)
    ny, nx = len(rows), len(cols)
    node_z = np.nan_to_num(zf[np.ix_(rows, cols)])
    node_x = grid.x0 + (cols + 0.5) * grid.cell
    node_y = grid.y0 + (rows + 0.5) * grid.cell
    cache: dict[int, str] = verdicts if verdicts is not None else {}
    m = margins or Margins()
    clear = (ndimage.distance_transform_edt(~g.hazard) * grid.cell if m.clearance_m > 0 and g.hazard.any()
             else None)
    start: int | None = None

    def verdict(k: int) -> str:
        if k not in cache:
            r, c = int(rows[k // nx]), int(cols[k % nx])
            cache[k] = _verdict(zf, grid, anchors, tcfg, ccfg, g, r, c)
            if cache[k] == USABLE and m.errors.any:
                cache[k] = _held(r, c) or USABLE
        return USABLE if (start_usable and k == start) else cache[k]

    def _held(r: int, c: int) -> str:
        xy = np.array([grid.x0 + (c + 0.5) * grid.cell, grid.y0 + (r + 0.5) * grid.cell])
        return node_held_reason(zf, grid, anchors, xy, tcfg, ccfg, m.errors)

    def cost(a: int, b: int) -> float:
        """An edge's cost over its length: 1 with room, up to 1 + weight at a hazard's edge;
        inf for an edge the caller found the body cannot pass (``blocked``)."""
        if (a, b) in cut:
            return math.inf
        if clear is None:
            return 1.0
        d = min(float(clear[rows[a // nx], cols[a % nx]]), float(clear[rows[b // nx], cols[b % nx]]))
        return 1.0 + m.weight * min(1.0, max(0.0, 1.0 - d / m.clearance_m))

    def point(k: int) -> F64:
        r, c = divmod(k, nx)
        return np.array([node_x[c], node_y[r], node_z[r, c]])

    def node_of(xy: F64) -> int | None:
        iy, ix, inside = grid.cell_index(np.array([xy[0]]), np.array([xy[1]]))
        if not inside[0]:
            return None
        cy = min(ny - 1, max(0, int(round((int(iy[0]) - rows[0]) / stride))))
        cx = min(nx - 1, max(0, int(round((int(ix[0]) - cols[0]) / stride))))
        return cy * nx + cx

    cut: set[tuple[int, int]] = set()
    for p, q in blocked:
        a, b = node_of(np.asarray(p, float)), node_of(np.asarray(q, float))
        if a is not None and b is not None:
            cut |= {(a, b), (b, a)}
    targets = np.asarray(targets_xy, float).reshape(-1, 2)
    start = node_of(np.asarray(start_xy, float))
    if start is None or verdict(start) != USABLE:
        why = "off the map" if start is None else verdict(start)
        return Plan(tuple(None for _ in targets), tuple(math.inf for _ in targets),
                    tuple(f"start: {why}" for _ in targets), why)
    paths: list[F64 | None] = []
    lengths: list[float] = []
    why_not: list[str] = []
    for t in targets:
        goal = node_of(t)
        if goal is None or verdict(goal) != USABLE:
            paths.append(None)
            lengths.append(math.inf)
            why_not.append("off the map" if goal is None else verdict(goal))
            continue
        found = _astar(start, goal, nx, ny, verdict, point, cost)
        if found is None:
            paths.append(None)
            lengths.append(math.inf)
            why_not.append("no safe path")
            continue
        chain, _ = found
        r, c = np.divmod(np.asarray(chain), nx)
        paths.append(np.column_stack([node_x[c], node_y[r]]))
        pts = np.column_stack([node_x[c], node_y[r], node_z[r, c]])
        lengths.append(float(np.linalg.norm(np.diff(pts, axis=0), axis=1).sum()))
        why_not.append("")
    return Plan(tuple(paths), tuple(lengths), tuple(why_not), "")


_STEPS = ((-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1))


def _astar(start: int, goal: int, nx: int, ny: int, verdict: Callable[[int], str],
           point: Callable[[int], F64], factor: Callable[[int, int], float] | None = None,
           ) -> tuple[list[int], float] | None:
    """A* over usable lattice nodes; the node chain and its cost (its 3-D length times each
    edge's ``factor`` >= 1, so the straight distance stays an admissible heuristic), or None."""
    goal_p = point(goal)
    best = {start: 0.0}
    came: dict[int, int] = {}
    heap = [(float(np.linalg.norm(point(start) - goal_p)), 0.0, start)]
    done: set[int] = set()
    while heap:
        _, cost, k = heapq.heappop(heap)
        if k in done:
            continue
        if k == goal:
            chain = [k]
            while chain[-1] != start:
                chain.append(came[chain[-1]])
            return chain[::-1], cost
        done.add(k)
        r, c = divmod(k, nx)
        pk = point(k)
        for dr, dc in _STEPS:
            rr, cc = r + dr, c + dc
            if not (0 <= rr < ny and 0 <= cc < nx):
                continue
            n = rr * nx + cc
            if n in done or verdict(n) != USABLE:
                continue
            pn = point(n)
            new = cost + float(np.linalg.norm(pn - pk)) * (factor(k, n) if factor is not None else 1.0)
            if new < best.get(n, math.inf) and math.isfinite(new):
                best[n] = new
                came[n] = k
                heapq.heappush(heap, (new + float(np.linalg.norm(pn - goal_p)), new, n))
    return None
