"""Tether statics of the Cliff-bot on the face (docs/algorithm.md §8, "Cliff-bot pose on the face").

Two Anchorbots on the plateau hold the Cliff-bot on tethers. The model is quasi-static:

1. **The tether's path.** A taut tether from the anchor's exit point ``A`` to the Cliff-bot's
   attachment point ``B`` lies in the vertical plane through them and is the shortest path
   that stays on or above the ground between them: the *upper convex hull* of ``A``, ``B``
   and the ground profile sampled along the horizontal segment ``A -> B`` (a string pulled
   tight over the terrain). Hull vertices other than the ends are *contacts*: the edge lip,
   a ledge, a rock; each acts as an intermediate anchor (JPL's Axel/DuAxel model of the
   tether as a shortest path with its contact points). Its length is the sum of the hull's
   3-D segment lengths; the direction the tether pulls the Cliff-bot is the last segment's.
2. **Equilibrium.** With unit pull directions ``u1``, ``u2``, the ground normal ``n`` at the
   Cliff-bot and its weight ``m g``: ``T1 u1 + T2 u2 + N n = m g e_z``: three equations
   for the two tensions and the normal force. The pose holds when ``T_min <= Ti <= T_max``
   (taut, not over-tensioned: gravity's along-face pull lies inside the cone of the two
   tethers) and ``N >= 0`` (the wheels stay on the face). Friction is ignored (it only
   widens the set of poses that hold), so the check is conservative.
3. **Forward kinematics.** Given the paid-out lengths ``l1, l2``, the Cliff-bot rests where
   both tethers are taut: ``L_i(p) = l_i`` for ``p`` on the ground;
   :func:`~fsw.core.team.tether_settle.settle` solves the two equations for ``(x, y)`` by
   Gauss-Newton from a guess (the previous pose).

The plane the Cliff-bot stands on is fitted in :mod:`fsw.core.team.standing_plane`.

Heights come from a 2.5D map ``z`` on a :class:`~fsw.core.geometry.MapGrid` (NaN: unknown);
the same code runs on the truth (the bench) and on the Cliff-bot's own map (its planner).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fsw.core.geometry import MapGrid
from fsw.core.team.standing_plane import plane_normal, plane_normals, ring
from fsw.core.team.tether_batch import heights_at, taut_tethers, vector_norm
from fsw.framework.params import param

F64 = NDArray[np.float64]
ZMap = NDArray[np.float32 | np.float64]  # a 2.5D map: heights, NaN unknown
BATCH_PLACES = 256  # places per batch of :func:`tether_states` (~2 x 256 ground profiles of a few hundred samples)
G = 9.81  # m/s^2 (the planet's value belongs in config when the bench plays Mars: TetherConfig.gravity_mps2)


@dataclass(frozen=True)
class TetherConfig:
    """The tethers, the winches' limits and the Cliff-bot's mass (docs/algorithm.md §8)."""

    spool_m: float = param(14.0, lo=0.5, hi=500.0, units="m", doc="tether length on each winch's spool")
    t_min_n: float = param(5.0, lo=0.0, hi=1e4, units="N", doc="below this a tether counts as slack")
    t_max_n: float = param(250.0, lo=1.0, hi=1e5, units="N", doc="over this a tether is over-tensioned")
    mass_kg: float = param(12.0, lo=0.1, hi=1000.0, units="kg", doc="the Cliff-bot's mass")
    gravity_mps2: float = param(G, lo=0.1, hi=30.0, units="m/s^2")
    anchor_exit_m: float = param(0.3, lo=0.0, hi=3.0, units="m", doc="tether exit above the anchor's ground")
    attach_m: float = param(0.15, lo=0.0, hi=2.0, units="m", doc="attachment above the Cliff-bot's ground")
    sample_m: float = param(0.03, lo=0.001, hi=1.0, units="m", doc="ground profile sampling along a tether")


@dataclass(frozen=True)
class TetherPath:
    """One taut tether from its anchor to the Cliff-bot."""

    length_m: float
    contacts: F64  # (K, 3) contact points between the ends, anchor side first
    pull: F64  # unit vector: the direction the tether pulls the Cliff-bot
    unknown: bool  # the tether passes over ground the map does not know


@dataclass(frozen=True)
class Statics:
    """Equilibrium of the Cliff-bot at one place: tensions, normal force and the verdict."""

    tensions_n: tuple[float, float]
    normal_n: float
    ok: bool
    reason: str  # "" when ok; else "slack", "over-tension", "off the face", "degenerate"
    tilt_deg: float = math.nan  # of the plane the Cliff-bot stands on (its normal's angle from vertical)


def ground_profile(z: ZMap, grid: MapGrid, a_xy: F64, b_xy: F64, step_m: float
                   ) -> tuple[F64, F64, bool]:
    """Heights along the horizontal segment ``a -> b`` (ends excluded): distance from ``a``,
    height, and whether any sample falls on unknown ground or off the map."""
    d = np.asarray(b_xy, float) - np.asarray(a_xy, float)
    span = float(math.hypot(d[0], d[1]))
    n = int(span / step_m)
    if n < 1:
        return np.zeros(0), np.zeros(0), False
    s = np.arange(1, n + 1, dtype=np.float64) * (span / (n + 1))
    ix = np.floor(((a_xy[0] + d[0] * s / span) - grid.x0) / grid.cell)  # as MapGrid.cell_index
    iy = np.floor(((a_xy[1] + d[1] * s / span) - grid.y0) / grid.cell)
    inside = (ix >= 0) & (ix < grid.nx) & (iy >= 0) & (iy < grid.ny)
    h = np.asarray(z[np.where(inside, iy, 0).astype(np.intp), np.where(inside, ix, 0).astype(np.intp)], np.float64)
    known = inside & np.isfinite(h)  # a sample off the map read cell (0, 0) above: one gather, then masked
    return s, np.where(known, h, -np.inf), not bool(known.all())


def upper_hull(s: F64, h: F64) -> NDArray[np.intp]:
    """Indices of the upper convex hull of the points ``(s, h)`` (``s`` increasing, both ends
    kept): QuickHull's upper half, the point farthest above each chord splitting it, so the
    work is one vectorised pass per contact (a tether has a few) instead of a Python loop over
    every sample."""
    out = [0]
    stack = [(0, len(s) - 1)]
    while stack:
        i, j = stack.pop()
        if j - i < 2:
            out.append(j)
            continue
        ss, hh = s[i + 1:j], h[i + 1:j]
        above = (s[j] - s[i]) * (hh - h[i]) - (h[j] - h[i]) * (ss - s[i])
        k = int(np.argmax(above))
        if above[k] <= 0.0:
            out.append(j)
            continue
        m = i + 1 + k
        stack.append((m, j))  # right part after the left: the stack pops the left first
        stack.append((i, m))
    return np.asarray(out, dtype=np.intp)


def tether_path(z: ZMap, grid: MapGrid, anchor: F64, bot: F64, cfg: TetherConfig) -> TetherPath:
    """The taut tether from ``anchor`` (its exit point, x y z) to ``bot`` (the attachment point)."""
    anchor = np.asarray(anchor, float)
    bot = np.asarray(bot, float)
    s, h, unknown = ground_profile(z, grid, anchor[:2], bot[:2], cfg.sample_m)
    span = float(math.hypot(*(bot[:2] - anchor[:2])))
    ss = np.empty(len(s) + 2)
    ss[0], ss[1:-1], ss[-1] = 0.0, s, span
    hh = np.empty(len(s) + 2)
    hh[0], hh[1:-1], hh[-1] = anchor[2], h, bot[2]
    idx = upper_hull(ss, hh)
    sv, hv = ss[idx], hh[idx]
    seg = np.hypot(sv[1:] - sv[:-1], hv[1:] - hv[:-1])
    direction = (bot[:2] - anchor[:2]) / span if span > 0 else np.zeros(2)
    inner = idx[1:-1]
    contacts = np.empty((len(inner), 3))
    contacts[:, 0] = anchor[0] + direction[0] * ss[inner]
    contacts[:, 1] = anchor[1] + direction[1] * ss[inner]
    contacts[:, 2] = hh[inner]
    last = idx[-2]  # the hull vertex the last segment comes from
    back = ss[-1] - ss[last]
    pull = np.array([-direction[0] * back, -direction[1] * back, hh[last] - bot[2]])
    norm = vector_norm(pull)
    return TetherPath(float(seg.sum()), contacts, pull / norm if norm > 0 else pull, unknown)


def attach_point(z: ZMap, grid: MapGrid, xy: F64, cfg: TetherConfig, footprint_m: float = 0.3) -> F64 | None:
    """The tethers' attachment point (x y z) with the Cliff-bot standing at ``xy``, as
    :func:`tether_state` puts it; None where the map does not know the ground under it."""
    got = _standing(z, grid, xy, cfg, footprint_m)
    return None if got is None else got[0]


def _standing(z: ZMap, grid: MapGrid, xy: F64, cfg: TetherConfig, footprint_m: float) -> tuple[F64, F64] | None:
    """The attachment point and the ground's upward normal with the Cliff-bot at ``xy`` (the
    plane of :func:`~fsw.core.team.standing_plane.surface_normal` round it); None where the map
    does not know the ground."""
    iy, ix, inside = grid.cell_index(np.array([xy[0]]), np.array([xy[1]]))
    if not inside[0]:
        return None
    px, py, design = ring(footprint_m, grid)
    h = heights_at(z, grid, float(xy[0]) + px, float(xy[1]) + py)  # h[0]: the ground under it (height_at)
    normal = plane_normal(design, h)
    if normal is None:
        return None
    return np.array([xy[0], xy[1], h[0]]) + cfg.attach_m * normal, normal

def clearance_over(z: ZMap, grid: MapGrid, anchor: F64, bot: F64, cfg: TetherConfig, cells: NDArray[np.bool_]) -> float:
    """The least height of the taut tether from ``anchor`` to ``bot`` (as :func:`tether_path`
    lays it) above the ground, over its profile's samples on the ``cells`` (a mask of the map);
    0 where it touches one of them, ``inf`` where it passes over none."""
    anchor = np.asarray(anchor, float)
    bot = np.asarray(bot, float)
    s, h, _ = ground_profile(z, grid, anchor[:2], bot[:2], cfg.sample_m)
    if not len(s):
        return math.inf
    span = float(math.hypot(*(bot[:2] - anchor[:2])))
    ix = np.floor((anchor[0] + (bot[0] - anchor[0]) * s / span - grid.x0) / grid.cell)  # as ground_profile
    iy = np.floor((anchor[1] + (bot[1] - anchor[1]) * s / span - grid.y0) / grid.cell)
    inside = (ix >= 0) & (ix < grid.nx) & (iy >= 0) & (iy < grid.ny)
    on = inside & cells[np.where(inside, iy, 0).astype(np.intp), np.where(inside, ix, 0).astype(np.intp)]
    if not on.any():
        return math.inf
    ss = np.concatenate([[0.0], s, [span]])
    hh = np.concatenate([[anchor[2]], h, [bot[2]]])
    idx = upper_hull(ss, hh)
    above = np.interp(s[on], ss[idx], hh[idx]) - h[on]
    return float(max(0.0, above.min()))




def statics(pull1: F64, pull2: F64, normal: F64, cfg: TetherConfig) -> Statics:
    """Solve ``T1 u1 + T2 u2 + N n = m g e_z`` and judge it against the tension limits."""
    a = np.column_stack([pull1, pull2, normal])
    tilt = math.degrees(math.acos(max(-1.0, min(1.0, float(normal[2]) / vector_norm(normal)))))
    weight = np.array([0.0, 0.0, cfg.mass_kg * cfg.gravity_mps2])
    if abs(np.linalg.det(a)) < 1e-9:
        return Statics((math.nan, math.nan), math.nan, False, "degenerate", tilt)
    t1, t2, n = np.linalg.solve(a, weight)
    return _judged(float(t1), float(t2), float(n), tilt, cfg)


def _judged(t1: float, t2: float, n: float, tilt: float, cfg: TetherConfig) -> Statics:
    """The equilibrium's tensions and normal force judged against the limits."""
    reason = ""
    if min(t1, t2) < cfg.t_min_n:
        reason = "slack"
    elif max(t1, t2) > cfg.t_max_n:
        reason = "over-tension"
    elif n < 0.0:
        reason = "off the face"
    return Statics((t1, t2), n, reason == "", reason, tilt)


def statics_many(pull1: F64, pull2: F64, normal: F64, cfg: TetherConfig) -> list[Statics]:
    """:func:`statics` of each row of ``pull1``, ``pull2``, ``normal`` (N, 3): one stacked
    LAPACK call each for the determinants and the solutions (the same routine per matrix)."""
    a = np.stack([pull1, pull2, normal], axis=2)  # columns: u1, u2, n
    weight = np.array([0.0, 0.0, cfg.mass_kg * cfg.gravity_mps2])
    det = np.linalg.det(a)
    ok = np.abs(det) >= 1e-9
    sol = np.full((len(a), 3), np.nan)
    if ok.any():
        sol[ok] = np.linalg.solve(a[ok], np.broadcast_to(weight[:, None], (int(ok.sum()), 3, 1)))[..., 0]
    out = []
    for k in range(len(a)):
        nk = normal[k]
        tilt = math.degrees(math.acos(max(-1.0, min(1.0, float(nk[2]) / vector_norm(nk)))))
        if not ok[k]:
            out.append(Statics((math.nan, math.nan), math.nan, False, "degenerate", tilt))
            continue
        t1, t2, n = sol[k]
        out.append(_judged(float(t1), float(t2), float(n), tilt, cfg))
    return out


@dataclass(frozen=True)
class TetherState:
    """Both tethers and the equilibrium with the Cliff-bot at one place."""

    paths: tuple[TetherPath, TetherPath]
    statics: Statics

    @property
    def lengths_m(self) -> tuple[float, float]:
        return (self.paths[0].length_m, self.paths[1].length_m)


def anchor_points(z: ZMap, grid: MapGrid, anchors_xy: F64, cfg: TetherConfig) -> F64:
    """The tethers' exit points: each anchor's ground height plus the exit height."""
    anchors_xy = np.asarray(anchors_xy, float).reshape(-1, 2)
    iy, ix, inside = grid.cell_index(anchors_xy[:, 0], anchors_xy[:, 1])
    if not inside.all():
        raise ValueError("an anchor lies off the map")
    zz = np.asarray(z, float)[iy, ix]
    if not np.isfinite(zz).all():
        raise ValueError("an anchor stands on ground the map does not know")
    return np.column_stack([anchors_xy, zz + cfg.anchor_exit_m])


def height_at(z: ZMap, grid: MapGrid, xy: F64 | tuple[float, float]) -> float:
    """Bilinear height at ``xy`` between the four nearest cell centres (NaN when one is unknown
    or off the map): continuous, so tether lengths are continuous in the Cliff-bot's place
    (a steep face on a coarse grid steps by ``cell * tan(slope)`` from one cell to the next)."""
    return float(heights_at(z, grid, np.array([float(xy[0])]), np.array([float(xy[1])]))[0])


def tether_state(z: ZMap, grid: MapGrid, anchors: F64, xy: F64, cfg: TetherConfig,
                 footprint_m: float = 0.3) -> TetherState | None:
    """Both tethers and the statics with the Cliff-bot standing at ``xy``; None where the map
    does not know the ground under it."""
    got = _standing(z, grid, xy, cfg, footprint_m)
    if got is None:
        return None
    bot, normal = got
    p1 = tether_path(z, grid, anchors[0], bot, cfg)
    p2 = tether_path(z, grid, anchors[1], bot, cfg)
    return TetherState((p1, p2), statics(p1.pull, p2.pull, normal, cfg))


def tether_states(z: ZMap, grid: MapGrid, anchors: F64, xys: F64, cfg: TetherConfig,
                  footprint_m: float = 0.3) -> list[TetherState | None]:
    """:func:`tether_state` at each of the places ``xys`` (N, 2), the same values, with the
    heights, tethers and statics of all of them in a few array passes
    (:mod:`fsw.core.team.tether_batch`; a handful of small passes per place cost the planner's
    lattice and the bench's settling most of their time)."""
    xys = np.asarray(xys, float).reshape(-1, 2)
    if len(xys) < 2:
        return [tether_state(z, grid, anchors, xy, cfg, footprint_m) for xy in xys]
    if len(xys) > BATCH_PLACES:  # the ground profiles of a batch are held at once: bound the memory
        return [st for k in range(0, len(xys), BATCH_PLACES)
                for st in tether_states(z, grid, anchors, xys[k:k + BATCH_PLACES], cfg, footprint_m)]
    with np.errstate(invalid="ignore"):  # a place that is not finite is off the map
        _, _, inside = grid.cell_index(xys[:, 0], xys[:, 1])
    px, py, design = ring(footprint_m, grid)
    h = heights_at(z, grid, (xys[:, :1] + px).ravel(), (xys[:, 1:] + py).ravel()).reshape(-1, 9)
    out: list[TetherState | None] = [None] * len(xys)
    at = np.flatnonzero(inside)
    normals = dict(zip(at.tolist(), plane_normals(design, h[at]), strict=True))
    held = [k for k, n in normals.items() if n is not None]
    if not held:
        return out
    nrm = np.array([normals[k] for k in held])
    bots = np.column_stack([xys[held], h[held, 0]]) + cfg.attach_m * nrm  # h[:, 0]: the ground under it
    paths = [TetherPath(*p) for p in taut_tethers(z, grid, np.tile(np.asarray(anchors, float)[:2], (len(held), 1)),
                                                  np.repeat(bots, 2, axis=0), cfg.sample_m)]
    judged = statics_many(np.array([p.pull for p in paths[0::2]]), np.array([p.pull for p in paths[1::2]]), nrm, cfg)
    for i, k in enumerate(held):
        out[k] = TetherState((paths[2 * i], paths[2 * i + 1]), judged[i])
    return out
