"""The Cliff-bot's task planner: paths to science targets on the face, under tether limits
(docs/algorithm.md §8, "Task execution").

The planner works on a 2.5D map (NaN: unknown) and the anchors' positions; the same code
plans on the map the Cliff-bot received (the flight) and on the truth (the bench's
brute-force check of what is reachable at all).

1. **Nodes.** Map cells every ``node_m``. A node is *usable* when the ground under the
   Cliff-bot's footprint is known, is not a hazard, and the tethers hold it there:
   - *hazard*: a rock (white top-hat relief over a ``rock_disc_m`` disc ``>= wheel_d_m``: a
     flat opening keeps every monotone profile, so the face, the lip and the foot are not
     rocks, while a bump narrower than the disc is), or ground steeper than
     ``max_slope_deg`` (a wall); hazards are grown by the footprint radius. Ledges and the
     lip are not hazards: the tethers carry the Cliff-bot over them;
   - *tethers*: both taut paths (:mod:`fsw.core.team.tether`) within the spool, over known
     ground, with no contact on a rock; on ground steeper than ``free_slope_deg`` the
     equilibrium must hold with both tensions in ``[T_min, T_max]`` and the wheels on the
     face (below it, the wheels hold the Cliff-bot and the winches only keep the tethers
     taut).
2. **Edges.** Usable 8-neighbours, weighted by their 3-D distance.
3. **Search.** Dijkstra from the Cliff-bot's node (``scipy.sparse.csgraph``): one search gives
   the shortest path to every target. A target that is not reached gets the reason of its
   own node (``unknown ground``, ``hazard``, ``out of tether reach``, ``slack``,
   ``over-tension``, ``off the face``, ``tether over a rock``, ``tether over unknown
   ground``, ``off the map``) or, when its node is usable, ``no safe path``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from fsw.core.geometry import MapGrid
from fsw.core.team.tether import TetherConfig, tether_state
from fsw.framework.params import param

F64 = NDArray[np.float64]

USABLE = "usable"
REASONS = ("off the map", "unknown ground", "hazard", "out of tether reach", "tether over unknown ground",
           "tether over a rock", "slack", "over-tension", "off the face", "degenerate")


@dataclass(frozen=True)
class ClimberConfig:
    """What the Cliff-bot can drive on, and the planner's lattice."""

    wheel_d_m: float = param(0.12, lo=0.01, hi=2.0, units="m", doc="wheel diameter: the critical length")
    footprint_m: float = param(0.3, lo=0.02, hi=5.0, units="m", doc="radius of the Cliff-bot's footprint")
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


@dataclass(frozen=True)
class Plan:
    """Paths from the start to each target, or the reason a target is not reachable."""

    paths: tuple[F64 | None, ...]  # (K, 2) xy waypoints from the start, per target
    lengths_m: tuple[float, ...]  # 3-D path length (inf when unreachable)
    reasons: tuple[str, ...]  # "" for a reached target
    start_reason: str  # "" when the start is usable


def _disc(radius_cells: int) -> NDArray[np.bool_]:
    r = max(0, radius_cells)
    yy, xx = np.mgrid[-r:r + 1, -r:r + 1]
    return np.asarray(xx * xx + yy * yy <= r * r)


def ground_layers(z: NDArray[np.floating], grid: MapGrid, cfg: ClimberConfig) -> Ground:
    """Rocks, hazards, known footprints and slope of every cell."""
    zf = np.asarray(z, np.float64)
    known = np.isfinite(zf)
    fill = np.where(known, zf, np.nanmin(zf) if known.any() else 0.0)
    rock_r = int(round(0.5 * cfg.rock_disc_m / grid.cell))
    opened = ndimage.grey_opening(fill, footprint=_disc(rock_r))
    rock = known & (fill - opened >= cfg.wheel_d_m)
    gy, gx = np.gradient(fill, grid.cell)
    slope = np.degrees(np.arctan(np.hypot(gx, gy)))
    foot = _disc(int(round(cfg.footprint_m / grid.cell)))
    steep = slope > cfg.max_slope_deg
    raw = rock | steep
    hazard = ndimage.binary_dilation(raw, structure=foot) & known
    known_foot = ndimage.binary_erosion(known, structure=foot, border_value=0)
    return Ground(rock, hazard, known_foot, slope.astype(np.float32))


def node_reasons(z: NDArray[np.floating], grid: MapGrid, anchors: F64, tcfg: TetherConfig, ccfg: ClimberConfig,
                 ground: Ground | None = None) -> tuple[NDArray[np.intp], NDArray[np.intp], list[str], Ground]:
    """The lattice (rows and columns of its nodes in the map) and each node's verdict."""
    g = ground if ground is not None else ground_layers(z, grid, ccfg)
    stride = max(1, int(round(ccfg.node_m / grid.cell)))
    rows = np.arange(stride // 2, grid.ny, stride)
    cols = np.arange(stride // 2, grid.nx, stride)
    rr, cc = np.meshgrid(rows, cols, indexing="ij")
    reasons: list[str] = []
    for iy, ix in zip(rr.ravel(), cc.ravel(), strict=True):
        reasons.append(_verdict(z, grid, anchors, tcfg, ccfg, g, int(iy), int(ix)))
    return rows, cols, reasons, g


def _verdict(z: NDArray[np.floating], grid: MapGrid, anchors: F64, tcfg: TetherConfig, ccfg: ClimberConfig,
             g: Ground, iy: int, ix: int) -> str:
    if not g.known[iy, ix]:
        return "unknown ground"
    if g.hazard[iy, ix]:
        return "hazard"
    xy = np.array([grid.x0 + (ix + 0.5) * grid.cell, grid.y0 + (iy + 0.5) * grid.cell])
    st = tether_state(z, grid, anchors, xy, tcfg, ccfg.footprint_m)
    if st is None:
        return "unknown ground"
    if max(st.lengths_m) > tcfg.spool_m:
        return "out of tether reach"
    if any(p.unknown for p in st.paths):
        return "tether over unknown ground"
    for p in st.paths:
        if len(p.contacts):
            cy, cx, inside = grid.cell_index(p.contacts[:, 0], p.contacts[:, 1])
            if (inside & g.rock[np.clip(cy, 0, grid.ny - 1), np.clip(cx, 0, grid.nx - 1)]).any():
                return "tether over a rock"
    if g.slope_deg[iy, ix] > ccfg.free_slope_deg and not st.statics.ok:
        return st.statics.reason
    return USABLE


def plan_targets(z: NDArray[np.floating], grid: MapGrid, anchors: F64, start_xy: F64, targets_xy: F64,
                 tcfg: TetherConfig, ccfg: ClimberConfig) -> Plan:
    """Shortest usable paths from ``start_xy`` to each target (module docstring)."""
    zf = np.asarray(z, np.float64)
    rows, cols, reasons, _ = node_reasons(zf, grid, anchors, tcfg, ccfg)
    ny, nx = len(rows), len(cols)
    usable = np.array([r == USABLE for r in reasons]).reshape(ny, nx)
    node_z = np.nan_to_num(zf[np.ix_(rows, cols)])
    node_x = grid.x0 + (cols + 0.5) * grid.cell
    node_y = grid.y0 + (rows + 0.5) * grid.cell
    stride = max(1, int(round(ccfg.node_m / grid.cell)))
    r, c = np.nonzero(usable)
    src, dst, w = [], [], []
    for dy, dx in ((0, 1), (1, 0), (1, 1), (1, -1)):
        r2, c2 = r + dy, c + dx
        ok = (r2 < ny) & (c2 >= 0) & (c2 < nx)
        ok[ok] = usable[r2[ok], c2[ok]]
        ra, ca, rb, cb = r[ok], c[ok], r2[ok], c2[ok]
        d = np.sqrt((node_x[ca] - node_x[cb]) ** 2 + (node_y[ra] - node_y[rb]) ** 2
                    + (node_z[ra, ca] - node_z[rb, cb]) ** 2)
        ia, ib = ra * nx + ca, rb * nx + cb
        src += [ia, ib]
        dst += [ib, ia]
        w += [d, d]
    graph = coo_matrix((np.concatenate(w), (np.concatenate(src), np.concatenate(dst))), shape=(ny * nx, ny * nx))

    def node_of(xy: F64) -> int | None:
        iy, ix, inside = grid.cell_index(np.array([xy[0]]), np.array([xy[1]]))
        if not inside[0]:
            return None
        cy = min(ny - 1, max(0, int(round((int(iy[0]) - rows[0]) / stride))))
        cx = min(nx - 1, max(0, int(round((int(ix[0]) - cols[0]) / stride))))
        return cy * nx + cx

    start = node_of(np.asarray(start_xy, float))
    targets = np.asarray(targets_xy, float).reshape(-1, 2)
    if start is None or not usable.flat[start]:
        why = "off the map" if start is None else reasons[start]
        return Plan(tuple(None for _ in targets), tuple(math.inf for _ in targets),
                    tuple(f"start: {why}" for _ in targets), why)
    dist, pred = dijkstra(graph.tocsr(), indices=start, return_predecessors=True)
    paths: list[F64 | None] = []
    lengths: list[float] = []
    why_not: list[str] = []
    for t in targets:
        k = node_of(t)
        if k is None or not np.isfinite(dist[k]):
            paths.append(None)
            lengths.append(math.inf)
            why_not.append("off the map" if k is None else reasons[k] if reasons[k] != USABLE else "no safe path")
            continue
        chain = [k]
        while chain[-1] != start:
            chain.append(int(pred[chain[-1]]))
        chain.reverse()
        r, c = np.divmod(np.asarray(chain), nx)
        paths.append(np.column_stack([node_x[c], node_y[r]]))
        lengths.append(float(dist[k]))
        why_not.append("")
    return Plan(tuple(paths), tuple(lengths), tuple(why_not), "")
