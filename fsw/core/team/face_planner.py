"""The Cliff-bot's task planner: paths to science targets on the face, under tether limits
(docs/algorithm.md §8, "Task execution").

The planner works on a 2.5D map (NaN: unknown) and the anchors' positions; the same code
plans on the map the Cliff-bot received (the flight) and on the truth (the bench's
brute-force check of what is reachable at all).

1. **Nodes.** Map cells every ``node_m``. A node is *usable* when the ground under the
   Cliff-bot's footprint (its wheels' outline at the heading it holds there,
   :func:`fsw.core.team.climber_ground.footprint_box`; the map's layers:
   :func:`fsw.core.team.climber_ground.ground_layers`) is known, is not a hazard, and the
   tethers hold it there:
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

import heapq
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from fsw.core.geometry import MapGrid
from fsw.core.team.climber_ground import ClimberConfig, Ground, ground_layers
from fsw.core.team.held_tension import (
    NOT_HELD,
    LengthErrors,
    held_at,
    held_reason,
    leaned_reason,
    length_covariance,
    length_offsets,
)
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
class Plan:
    """Paths from the start to each target, or the reason a target is not reachable."""

    paths: tuple[F64 | None, ...]  # (K, 2) xy waypoints from the start, per target
    lengths_m: tuple[float, ...]  # 3-D path length (inf when unreachable)
    reasons: tuple[str, ...]  # "" for a reached target
    start_reason: str  # "" when the start is usable


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
    if st is None or st.statics.tilt_deg + errors.plane_error_deg <= ccfg.free_slope_deg:
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
               settle_at: Settle = settle, leaving: bool = False) -> str:
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
    brute force keeps them, ``hil_sim.team.team_eval``). Directed: the way back may differ.

    ``leaving``: the body stands at ``a``, which a newer map may have made a hazard (a rock
    measured beside it): the way's first places may lie in that hazard as long as each is no
    nearer a rock or a wall cell than ``a`` is (:func:`raw_hazard_distance`); from the first
    place out of it on, every place is judged as above."""
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
    ia, ja, _ = grid.cell_index(np.asarray(a, float)[:1], np.asarray(a, float)[1:])
    leave_d = raw_hazard_distance(grid, g, ccfg, np.asarray(a, float)) \
        if leaving and bool(g.hazard[int(ia[0]), int(ja[0])]) else None
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
            if leave_d is None or raw_hazard_distance(grid, g, ccfg, xy) < leave_d - 1e-9:
                return "hazard"
        else:
            leave_d = None  # out of the hazard it stood in: judged as any place from here on
        why = _tether_verdict(got[1], grid, tcfg, ccfg, g)
        if why != USABLE:
            return why
        was, over = over, rocky and _over_rock(z, grid, anchors, xy, tcfg, ccfg, near)
        if was or over:
            why = _swept_rock(z, grid, anchors, la, lb, float(f) - 1.0 / n, 1.0 / n, last, tcfg, ccfg, g, settle_at)
            if why:
                return why
        if held and errors is not None and got[1].statics.tilt_deg + errors.plane_error_deg > ccfg.free_slope_deg:
            why = leaned_reason(got[1], tcfg, ccfg.free_slope_deg, errors.plane_error_deg) or held_at(
                z, grid, anchors, xy, got[1], (1.0 - f) * off_a + f * off_b, tcfg, ccfg.free_slope_deg)
            if why:
                return why
    if float(np.hypot(*(xy - np.asarray(b, float)))) > ccfg.node_m:
        return OFF_THE_WAY
    return ""


def raw_hazard_distance(grid: MapGrid, g: Ground, ccfg: ClimberConfig, xy: F64) -> float:
    """The distance (m) from place ``xy`` to the nearest raw hazard cell (a rock, ground steeper
    than ``max_slope_deg``: what ``g.hazard`` grows by the footprint) within the footprint's
    reach of it (its diagonal and a cell); inf with none there (the place is no hazard)."""
    reach = math.hypot(ccfg.body_half_length_m, ccfg.body_half_width_m) + grid.cell
    k = int(math.ceil(reach / grid.cell)) + 1
    iy, ix, _ = grid.cell_index(np.array([xy[0]]), np.array([xy[1]]))
    r0, r1 = max(0, int(iy[0]) - k), min(grid.ny, int(iy[0]) + k + 1)
    c0, c1 = max(0, int(ix[0]) - k), min(grid.nx, int(ix[0]) + k + 1)
    ry, rx = np.nonzero(g.rock[r0:r1, c0:c1] | (g.slope_deg[r0:r1, c0:c1] > ccfg.max_slope_deg))
    if not len(ry):
        return math.inf
    d = np.hypot(grid.x0 + (c0 + rx + 0.5) * grid.cell - xy[0], grid.y0 + (r0 + ry + 0.5) * grid.cell - xy[1])
    return float(d.min())


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
    leaving: dict[int, str] = {}  # hazard nodes judged for the way out of a hazard start (this start's)
    leave_d: float | None = None  # the start's distance from its nearest raw hazard cell (it stands in one)
    blob: NDArray[np.bool_] | None = None  # the hazard's cells connected to the start's
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
        if start_usable and k == start:
            return USABLE
        if leave_d is not None and cache[k] == "hazard":
            return leaving[k] if k in leaving else _leavable(k)
        return cache[k]

    def _leavable(k: int) -> str:
        """A hazard node on the way out of the hazard the start stands in: judged as a node
        without its hazard when it lies in that hazard (connected to the start's cell) no nearer
        a raw hazard cell than the start."""
        r, c = int(rows[k // nx]), int(cols[k % nx])
        xy = np.array([grid.x0 + (c + 0.5) * grid.cell, grid.y0 + (r + 0.5) * grid.cell])
        assert leave_d is not None and blob is not None
        if not blob[r, c] or raw_hazard_distance(grid, g, ccfg, xy) < leave_d - 1e-9:
            leaving[k] = "hazard"
        else:
            why = _tether_verdict(tether_state(zf, grid, anchors, xy, tcfg, ccfg.footprint_m), grid, tcfg, ccfg, g)
            leaving[k] = (_held(r, c) or USABLE) if why == USABLE and m.errors.any else why
        return leaving[k]

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
    if start is not None and start_usable and verdict(start) == USABLE and cache[start] == "hazard":
        # it stands in a hazard (a newer map measured a rock beside it): the way out of it may
        # cross hazard nodes that are no nearer a rock than the start (docs/team.md)
        r0, c0 = int(rows[start // nx]), int(cols[start % nx])
        labels, _ = ndimage.label(g.hazard)
        blob = labels == labels[r0, c0]
        leave_d = raw_hazard_distance(grid, g, ccfg, np.array([grid.x0 + (c0 + 0.5) * grid.cell,
                                                               grid.y0 + (r0 + 0.5) * grid.cell]))
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


def lattice_nodes_near(grid: MapGrid, ccfg: ClimberConfig, xy: F64, radius_m: float) -> list[int]:
    """The planner's lattice nodes (:func:`plan_targets`' indices, its ``verdicts`` keys) within
    ``radius_m`` of ``xy``, the nearest one always; none when ``xy`` is off the map."""
    p = np.asarray(xy, float).reshape(2)
    _, _, inside = grid.cell_index(p[:1], p[1:])
    if not inside[0]:
        return []
    stride = max(1, int(round(ccfg.node_m / grid.cell)))
    rows, cols = np.arange(stride // 2, grid.ny, stride), np.arange(stride // 2, grid.nx, stride)
    d = np.hypot(*np.meshgrid(grid.x0 + (cols + 0.5) * grid.cell - p[0],
                              grid.y0 + (rows + 0.5) * grid.cell - p[1]))  # (rows, cols)
    near = d <= radius_m
    near.flat[int(np.argmin(d))] = True
    return np.flatnonzero(near).tolist()


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
