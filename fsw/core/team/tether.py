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
   both tethers are taut: ``L_i(p) = l_i`` for ``p`` on the ground; :func:`settle` solves
   the two equations for ``(x, y)`` by Gauss-Newton from a guess (the previous pose).

Heights come from a 2.5D map ``z`` on a :class:`~fsw.core.geometry.MapGrid` (NaN: unknown);
the same code runs on the truth (the bench) and on the Cliff-bot's own map (its planner).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fsw.core.geometry import MapGrid
from fsw.core.team.tether_batch import heights_at, taut_tethers, vector_norm
from fsw.framework.params import param

F64 = NDArray[np.float64]
# the gufunc np.linalg.lstsq calls (numpy >= 2.0), for fitting many planes in one call (_plane_normals)
_GELSD: np.ufunc | None = getattr(np.linalg._umath_linalg, "lstsq", None)  # type: ignore[attr-defined]
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
    plane of :func:`surface_normal` round it); None where the map does not know the ground."""
    iy, ix, inside = grid.cell_index(np.array([xy[0]]), np.array([xy[1]]))
    if not inside[0]:
        return None
    px, py, design = _ring(footprint_m, grid)
    h = heights_at(z, grid, float(xy[0]) + px, float(xy[1]) + py)  # h[0]: the ground under it (height_at)
    normal = _plane_normal(design, h)
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


_RING = np.arange(8) * (np.pi / 4)
_RING_COS, _RING_SIN = np.cos(_RING), np.sin(_RING)


def _ring(radius_m: float, grid: MapGrid) -> tuple[F64, F64, F64]:
    """The footprint's centre and eight points on the circle of ``radius_m`` (at least a cell),
    and the plane fit's design matrix over them (columns x, y, 1): read-only, made once per
    radius (every tether state fits a plane over the same ring)."""
    return _ring_of(max(radius_m, grid.cell))


@functools.lru_cache(maxsize=16)
def _ring_of(r: float) -> tuple[F64, F64, F64]:
    px = np.empty(9)
    py = np.empty(9)
    px[0], px[1:] = 0.0, r * _RING_COS
    py[0], py[1:] = 0.0, r * _RING_SIN
    design = np.column_stack([px, py, np.ones_like(px)])
    for a in (px, py, design):
        a.flags.writeable = False
    return px, py, design


def _plane_normal(design: F64, h: F64) -> F64 | None:
    """The upward unit normal of the plane fitted to the heights ``h`` at the ring's points
    (``design``, :func:`_ring`; NaN: left out); None when the centre or more than half of the
    circle is unknown. Where every height is known (most places) the whole design matrix is the
    fit's, with no selection."""
    ok = np.isfinite(h)
    if not ok[0]:
        return None
    if ok.all():
        a, hk = design, h
    elif ok.sum() < 5:
        return None
    else:
        a, hk = design[ok], h[ok]
    (gx, gy, _), *_ = np.linalg.lstsq(a, hk, rcond=None)
    n = np.array([-gx, -gy, 1.0])
    return n / vector_norm(n)


def _plane_normals(design: F64, h: F64) -> list[F64 | None]:
    """:func:`_plane_normal` of each row of ``h`` (N, 9), the same values: the rows whose every
    height is known (most places) fitted in one call of the gufunc ``np.linalg.lstsq`` wraps
    (LAPACK's ``gelsd`` on each matrix, with lstsq's default ``rcond``), the others one at a
    time. A batch of tether states fits a plane per place, and lstsq's checks and wrapping cost
    several times its solve for a 9 x 3 fit."""
    gelsd = _GELSD
    full = np.isfinite(h).all(axis=1) if gelsd is not None else np.zeros(len(h), bool)
    out: list[F64 | None] = [None] * len(h)
    if gelsd is not None and full.any():
        rcond = np.finfo(np.float64).eps * max(design.shape)
        with np.errstate(over="ignore", divide="ignore", under="ignore"):
            fits: F64 = gelsd(design, h[full][:, :, None], rcond, signature="ddd->ddid")[0][:, :, 0]
        for k, (gx, gy, _) in zip(np.flatnonzero(full), fits, strict=True):
            n = np.array([-gx, -gy, 1.0])
            out[int(k)] = n / vector_norm(n)
    for k in np.flatnonzero(~full):
        out[int(k)] = _plane_normal(design, h[k])
    return out


def surface_normal(z: ZMap, grid: MapGrid, xy: F64, radius_m: float) -> F64 | None:
    """Unit upward normal of the plane fitted to the ground at ``xy`` and at eight points on
    the circle of ``radius_m`` around it (bilinear heights, :func:`height_at`, so the normal
    and the attachment point move continuously with the Cliff-bot); points on unknown ground
    or off the map are left out; None when the centre or more than half of the circle is."""
    px, py, design = _ring(radius_m, grid)
    return _plane_normal(design, heights_at(z, grid, float(xy[0]) + px, float(xy[1]) + py))


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
    px, py, design = _ring(footprint_m, grid)
    h = heights_at(z, grid, (xys[:, :1] + px).ravel(), (xys[:, 1:] + py).ravel()).reshape(-1, 9)
    out: list[TetherState | None] = [None] * len(xys)
    at = np.flatnonzero(inside)
    normals = dict(zip(at.tolist(), _plane_normals(design, h[at]), strict=True))
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


def settle(z: ZMap, grid: MapGrid, anchors: F64, lengths: tuple[float, float], guess_xy: F64,
           cfg: TetherConfig, iterations: int = 30, tol_m: float = 1e-3) -> tuple[F64, TetherState] | None:
    """Forward kinematics: where both tethers, paid out to ``lengths``, are taut on the ground.

    Gauss-Newton on ``L_i(x, y) = l_i`` from ``guess_xy`` (the last pose): the Jacobian by
    central differences of the tether lengths at one map cell, each step halved until the
    residual shrinks. On a rough face steeper than about 75 degrees the lengths are rough
    functions of ``(x, y)`` at the scale of a cell (a centimetre across the face is several
    up it) and Gauss-Newton can cycle; then a Nelder-Mead search on the largest length
    residual from the best place seen (:func:`_settle_search`) decides, with the same
    acceptance. None when neither finds both tethers taut within it (the lengths cannot both
    be taut: the Cliff-bot would hang on one tether)."""
    xy = np.asarray(guess_xy, float).copy()
    h = grid.cell
    target = np.asarray(lengths, float)
    probes = np.array([[h, 0.0], [-h, 0.0], [0.0, h], [0.0, -h]])
    known: TetherState | None = None  # the state at ``xy`` when the last step's trial computed it
    accept = 10 * tol_m + 0.25 * h
    best: tuple[float, F64] = (math.inf, xy.copy())
    for _ in range(iterations):
        st = known if known is not None else tether_state(z, grid, anchors, xy, cfg)
        known = None
        if st is None:
            return None
        r = np.asarray(st.lengths_m) - target
        if float(np.max(np.abs(r))) < best[0]:
            best = (float(np.max(np.abs(r))), xy.copy())
        if np.max(np.abs(r)) < tol_m:
            return xy, st
        jac = np.empty((2, 2))
        around = tether_states(z, grid, anchors, xy + probes, cfg)  # x + h, x - h, y + h, y - h
        for k in range(2):
            hi, lo = around[2 * k], around[2 * k + 1]
            if hi is None or lo is None:
                return None
            jac[:, k] = (np.asarray(hi.lengths_m) - np.asarray(lo.lengths_m)) / (2 * h)
        if abs(np.linalg.det(jac)) < 1e-9:
            return None
        step = np.linalg.solve(jac, r)
        n = vector_norm(step)
        if n > 0.5:  # a damped step: the ground under the Cliff-bot is only known locally
            step *= 0.5 / n
        # Backtracking: a contact appearing or vanishing makes the lengths kink, and a full
        # Gauss-Newton step can cycle across the kink; halve it until the residual shrinks.
        xy, known = _backtrack(z, grid, anchors, xy, step, target, vector_norm(r), cfg)
    st = known if known is not None else tether_state(z, grid, anchors, xy, cfg)
    if st is not None and np.max(np.abs(np.asarray(st.lengths_m) - target)) < accept:
        return xy, st
    return _settle_search(z, grid, anchors, target, best[1], cfg, accept)


_HALVINGS = 0.5 ** np.arange(7)  # settle's step and its six halvings (exact: powers of two)


def _backtrack(z: ZMap, grid: MapGrid, anchors: F64, xy: F64, step: F64, target: F64, r_norm: float,
               cfg: TetherConfig) -> tuple[F64, TetherState | None]:
    """:func:`settle`'s backtracking step from ``xy``: the step, halved until the residual at
    ``xy - step`` is below ``r_norm`` (at most six times; after the sixth the step is halved
    once more and taken), and the state there. Every trial place is worked out in one
    :func:`tether_states` batch (the same values as one at a time), the last one included: on
    a rough face most steps are halved a few times, and a batch costs about as much as two
    places one at a time."""
    places = xy - _HALVINGS[:, None] * step  # the trials, then the place taken when none shrinks
    states = tether_states(z, grid, anchors, places, cfg)
    for k in range(len(places) - 1):
        trial = states[k]
        if trial is not None and vector_norm(np.asarray(trial.lengths_m) - target) < r_norm:
            return places[k], trial
    return places[-1], states[-1]


def _settle_search(z: ZMap, grid: MapGrid, anchors: F64, target: F64, xy0: F64, cfg: TetherConfig,
                   accept_m: float) -> tuple[F64, TetherState] | None:
    """Nelder-Mead (``scipy.optimize``) on ``max_i |L_i(x, y) - l_i|`` from ``xy0``, its first
    simplex a quarter cell wide; the place found when it is within ``accept_m``."""
    from scipy.optimize import minimize

    def worst(p: F64) -> float:
        st = tether_state(z, grid, anchors, p, cfg)
        return float(np.max(np.abs(np.asarray(st.lengths_m) - target))) if st is not None else math.inf

    d = 0.25 * grid.cell
    res = minimize(worst, xy0, method="Nelder-Mead",
                   options={"xatol": 1e-4, "fatol": 1e-4, "maxfev": 120,
                            "initial_simplex": np.array([xy0, xy0 + [d, 0.0], xy0 + [0.0, d]])})
    xy = np.asarray(res.x, float)
    st = tether_state(z, grid, anchors, xy, cfg)
    if st is not None and float(np.max(np.abs(np.asarray(st.lengths_m) - target))) < accept_m:
        return xy, st
    return None


@dataclass(frozen=True)
class SettledMany:
    """What :func:`settle_many` found for each pair of lengths: ``places[i]`` the place and its
    state where both tethers are taut (None: they cannot both be, as :func:`settle`'s None),
    ``unsettled[i]`` True where its budget ended with neither (the place is not decided)."""

    places: list[tuple[F64, TetherState] | None]
    unsettled: NDArray[np.bool_]


FULL_STEPS = 6  # settle_many's first pass: Gauss-Newton steps taken whole (damped only)
SETTLE_MANY_ITERATIONS = 30  # its second pass, backtracking, as many steps as :func:`settle`
_BACKTRACK = 6  # halvings of a step that does not shrink the residual, as :func:`settle`'s
SEARCH_RADII = (4.0, 2.0, 1.0, 0.5, 0.25, 0.125, 0.0625)  # the compass search's steps, in map cells, each tried twice
_COMPASS = np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0],
                     [0.7071, 0.7071], [-0.7071, 0.7071], [0.7071, -0.7071], [-0.7071, -0.7071]])


def settle_many(z: ZMap, grid: MapGrid, anchors: F64, lengths: F64, guesses_xy: F64, cfg: TetherConfig,
                iterations: int = SETTLE_MANY_ITERATIONS, tol_m: float = 1e-3) -> SettledMany:
    """:func:`settle` of many pairs of lengths ``lengths`` (M, 2), each from its guess
    ``guesses_xy`` (M, 2), in batches and at a bounded cost. Each Gauss-Newton step evaluates
    every place still going and its four Jacobian probes in one :func:`tether_states` batch and
    solves all the 2 x 2 steps at once. Three stages, each for the places the last left going:

    1. ``FULL_STEPS`` whole steps (damped only: a full step can jump a kink of the lengths, a
       contact appearing or vanishing, that a backtracking step stops at);
    2. from the best place each reached, ``iterations`` steps each halved until the residual
       shrinks (at most ``_BACKTRACK`` times, one batch per halving, as :func:`settle`'s); a
       place no halving improves is stuck and stops;
    3. where the best place is not within :func:`settle`'s acceptance (``10 tol_m`` plus a
       quarter cell), the compass search that stands for :func:`settle`'s Nelder-Mead
       (:func:`_compass_search`: on a rough face the lengths are rough functions of the place
       at the scale of a cell and Gauss-Newton stalls).

    A place off the known ground or with a singular Jacobian in stage 2 is None (the lengths
    cannot both be taut there), as :func:`settle`'s; one within ``tol_m`` is settled, and the
    others at their best place when it is within the acceptance. The rest are *unsettled*
    (``SettledMany.unsettled``): undecided, for the caller to refuse. A place costs at most
    ``5 (FULL_STEPS + 1) + 5 (iterations + 1) + _BACKTRACK iterations + 16 len(SEARCH_RADII)``
    tether states, whatever the ground."""
    target = np.asarray(lengths, float).reshape(-1, 2)
    guesses = np.asarray(guesses_xy, float).reshape(-1, 2)
    out = _Batch(len(target))
    _gauss_newton(z, grid, anchors, target, guesses, cfg, np.arange(len(target)), FULL_STEPS, 0, tol_m, out)
    again = np.flatnonzero(out.going)
    # from the best place the whole steps reached (their guess where they reached none)
    start = np.where(np.isfinite(out.best_res)[:, None], out.best_xy, guesses)
    _gauss_newton(z, grid, anchors, target, start, cfg, again, iterations, _BACKTRACK, tol_m, out)
    accept = 10 * tol_m + 0.25 * grid.cell
    _compass_search(z, grid, anchors, target, cfg, np.flatnonzero(out.going & (out.best_res >= accept)), out)
    unsettled = out.going.copy()  # the budget ended: settled where its best place is within acceptance
    for i in np.flatnonzero(out.going):
        st = out.best_st[i]
        if out.best_res[i] < accept and st is not None:
            out.places[int(i)] = (out.best_xy[i].copy(), st)
            unsettled[i] = False
    return SettledMany(out.places, unsettled)


class _Batch:
    """The state of :func:`settle_many`'s places: what each found, whether it is still going,
    the best place each reached."""

    def __init__(self, m: int) -> None:
        self.places: list[tuple[F64, TetherState] | None] = [None] * m
        self.going = np.ones(m, bool)  # neither settled nor refused yet
        self.best_res = np.full(m, math.inf)
        self.best_xy = np.zeros((m, 2))
        self.best_st: list[TetherState | None] = [None] * m


def _gauss_newton(z: ZMap, grid: MapGrid, anchors: F64, target: F64, guesses: F64, cfg: TetherConfig,
                  which: NDArray[np.intp], iterations: int, backtrack: int, tol_m: float, out: _Batch) -> None:
    """``iterations`` batched Gauss-Newton steps of the places ``which`` from their guesses
    (:func:`settle_many`), each step halved at most ``backtrack`` times until the residual
    shrinks (0: whole steps, a pass whose places that leave the known ground or meet a singular
    Jacobian are left going, for the backtracking pass to decide); records in ``out``."""
    xy = guesses.copy()
    h = grid.cell
    probes = np.array([[0.0, 0.0], [h, 0.0], [-h, 0.0], [0.0, h], [0.0, -h]])
    active = np.asarray(which, np.intp)
    whole = backtrack == 0
    for it in range(iterations + 1):
        if not len(active):
            return
        states = tether_states(z, grid, anchors, (xy[active, None, :] + probes).reshape(-1, 2), cfg)
        lens = _lengths_of(states).reshape(len(active), 5, 2)
        on = np.isfinite(lens).all(axis=(1, 2))
        out.going[active[~on]] = not whole  # off the known ground: None, as settle's
        centre = [states[5 * j] for j in np.flatnonzero(on)]
        active, lens = active[on], lens[on]
        r = lens[:, 0] - target[active]
        worst = np.max(np.abs(r), axis=1)
        for j in np.flatnonzero(worst < out.best_res[active]):
            i = int(active[j])
            out.best_res[i], out.best_xy[i], out.best_st[i] = worst[j], xy[i].copy(), centre[j]
        done = worst < tol_m
        for j in np.flatnonzero(done):
            st = centre[j]
            if st is not None:  # its lengths are finite: it has a state
                out.places[int(active[j])] = (xy[active[j]].copy(), st)
        out.going[active[done]] = False
        if it == iterations:
            return
        active, lens, r = active[~done], lens[~done], r[~done]
        jac = np.stack([lens[:, 1] - lens[:, 2], lens[:, 3] - lens[:, 4]], axis=2) / (2 * h)  # dL_i/dx_k
        singular = np.abs(np.linalg.det(jac)) < 1e-9
        out.going[active[singular]] = not whole  # None, as settle's
        active, jac, r = active[~singular], jac[~singular], r[~singular]
        if not len(active):
            return
        step = np.linalg.solve(jac, r[:, :, None])[:, :, 0]
        n = np.linalg.norm(step, axis=1)
        step *= np.where(n > 0.5, 0.5 / np.maximum(n, 1e-300), 1.0)[:, None]  # damped as settle's steps
        if backtrack:
            step, stuck = _backtracked(z, grid, anchors, xy[active], step, target[active], r, cfg, backtrack)
            xy[active] -= step
            active = active[~stuck]  # no step shrinks its residual: left going, judged at its best place
        else:
            xy[active] -= step


def _compass_search(z: ZMap, grid: MapGrid, anchors: F64, target: F64, cfg: TetherConfig,
                    which: NDArray[np.intp], out: _Batch) -> None:
    """The search :func:`settle` makes where Gauss-Newton stalls (its Nelder-Mead on the largest
    length residual), batched and bounded: from the best place each of ``which`` reached, eight
    compass points at each radius of ``SEARCH_RADII`` (twice each), one :func:`tether_states`
    batch per move for all of them, each place moving to its best point when that lowers its
    residual; records the best place in ``out``."""
    active = np.asarray(which, np.intp)
    for radius in SEARCH_RADII:
        for _ in range(2):
            if not len(active):
                return
            pts = out.best_xy[active, None, :] + radius * grid.cell * _COMPASS
            states = tether_states(z, grid, anchors, pts.reshape(-1, 2), cfg)
            worst = np.max(np.abs(_lengths_of(states).reshape(len(active), 8, 2) - target[active, None, :]), axis=2)
            worst = np.where(np.isfinite(worst), worst, np.inf)
            pick = np.argmin(worst, axis=1)
            for j in np.flatnonzero(worst[np.arange(len(active)), pick] < out.best_res[active]):
                i, k = int(active[j]), int(pick[j])
                out.best_res[i], out.best_xy[i], out.best_st[i] = worst[j, k], pts[j, k].copy(), states[8 * j + k]


def _lengths_of(states: list[TetherState | None]) -> F64:
    """Both lengths of each state (N, 2), NaN where there is none."""
    out = np.full((len(states), 2), np.nan)
    for k, s in enumerate(states):
        if s is not None:
            out[k] = s.lengths_m
    return out


def _backtracked(z: ZMap, grid: MapGrid, anchors: F64, xy: F64, step: F64, target: F64, r: F64,
                 cfg: TetherConfig, halvings: int) -> tuple[F64, NDArray[np.bool_]]:
    """Each place's step, halved until the residual at ``xy - step`` shrinks (one batch per
    halving, of the places still halving; :func:`settle`'s backtracking, batched), and whether
    none of the ``halvings`` trials shrank it (the place is stuck: :func:`settle` would step on
    by the last halved step, find the same step from there and stall until its budget ends)."""
    step = step.copy()
    r_norm = np.linalg.norm(r, axis=1)
    halving = np.arange(len(xy))
    for _ in range(halvings):
        trial = _lengths_of(tether_states(z, grid, anchors, xy[halving] - step[halving], cfg))
        shrank = np.isfinite(trial).all(axis=1) & (np.linalg.norm(trial - target[halving], axis=1) < r_norm[halving])
        halving = halving[~shrank]
        if not len(halving):
            break
        step[halving] *= 0.5
    stuck = np.zeros(len(xy), bool)
    stuck[halving] = True
    return step, stuck
