"""The tether statics as first written (one height at a time, one tether at a time): the
reference that ``fsw.core.team.tether``'s faster functions must match bit for bit
(tests/fsw/core/team/test_tether_batch.py)."""

from __future__ import annotations

import math

import numpy as np

from fsw.core.geometry import MapGrid
from fsw.core.team.tether import F64, Statics, TetherConfig, TetherPath, TetherState, ZMap


def ground_profile(z: ZMap, grid: MapGrid, a_xy: F64, b_xy: F64, step_m: float) -> tuple[F64, F64, bool]:
    d = np.asarray(b_xy, float) - np.asarray(a_xy, float)
    span = float(math.hypot(d[0], d[1]))
    n = int(span / step_m)
    if n < 1:
        return np.zeros(0), np.zeros(0), False
    s = np.arange(1, n + 1, dtype=np.float64) * (span / (n + 1))
    xs = a_xy[0] + d[0] * s / span
    ys = a_xy[1] + d[1] * s / span
    iy, ix, inside = grid.cell_index(xs, ys)
    h = np.full(n, np.nan)
    h[inside] = z[iy[inside], ix[inside]]
    unknown = bool((~np.isfinite(h)).any())
    return s, np.where(np.isfinite(h), h, -np.inf).astype(np.float64), unknown


def upper_hull(s: F64, h: F64) -> np.ndarray:
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
        stack.append((m, j))
        stack.append((i, m))
    return np.asarray(out, dtype=np.intp)


def tether_path(z: ZMap, grid: MapGrid, anchor: F64, bot: F64, cfg: TetherConfig) -> TetherPath:
    anchor = np.asarray(anchor, float)
    bot = np.asarray(bot, float)
    s, h, unknown = ground_profile(z, grid, anchor[:2], bot[:2], cfg.sample_m)
    span = float(math.hypot(*(bot[:2] - anchor[:2])))
    ss = np.concatenate([[0.0], s, [span]])
    hh = np.concatenate([[anchor[2]], h, [bot[2]]])
    idx = upper_hull(ss, hh)
    seg = np.hypot(np.diff(ss[idx]), np.diff(hh[idx]))
    direction = (bot[:2] - anchor[:2]) / span if span > 0 else np.zeros(2)
    inner = idx[1:-1]
    contacts = np.column_stack([anchor[0] + direction[0] * ss[inner], anchor[1] + direction[1] * ss[inner],
                                hh[inner]])
    last = idx[-2]
    pull = np.array([-direction[0] * (ss[-1] - ss[last]), -direction[1] * (ss[-1] - ss[last]), hh[last] - bot[2]])
    norm = float(np.linalg.norm(pull))
    return TetherPath(float(seg.sum()), contacts, pull / norm if norm > 0 else pull, unknown)


def height_at(z: ZMap, grid: MapGrid, xy: F64 | tuple[float, float]) -> float:
    fx = (float(xy[0]) - grid.x0) / grid.cell - 0.5
    fy = (float(xy[1]) - grid.y0) / grid.cell - 0.5
    ix, iy = int(math.floor(fx)), int(math.floor(fy))
    if not (0 <= ix < grid.nx - 1 and 0 <= iy < grid.ny - 1):
        return math.nan
    ax, ay = fx - ix, fy - iy
    q = np.asarray(z[iy:iy + 2, ix:ix + 2], float)
    return float((1 - ay) * ((1 - ax) * q[0, 0] + ax * q[0, 1]) + ay * ((1 - ax) * q[1, 0] + ax * q[1, 1]))


def surface_normal(z: ZMap, grid: MapGrid, xy: F64, radius_m: float) -> F64 | None:
    r = max(radius_m, grid.cell)
    ang = np.arange(8) * (np.pi / 4)
    px = np.concatenate([[0.0], r * np.cos(ang)])
    py = np.concatenate([[0.0], r * np.sin(ang)])
    h = np.array([height_at(z, grid, (float(xy[0]) + a, float(xy[1]) + b)) for a, b in zip(px, py, strict=True)])
    ok = np.isfinite(h)
    if not ok[0] or ok.sum() < 5:
        return None
    a = np.column_stack([px, py, np.ones_like(px)])[ok]
    (gx, gy, _), *_ = np.linalg.lstsq(a, h[ok], rcond=None)
    n = np.array([-gx, -gy, 1.0])
    return n / np.linalg.norm(n)


def reference_statics(pull1: F64, pull2: F64, normal: F64, cfg: TetherConfig) -> Statics:
    a = np.column_stack([pull1, pull2, normal])
    tilt = math.degrees(math.acos(max(-1.0, min(1.0, float(normal[2]) / float(np.linalg.norm(normal))))))
    weight = np.array([0.0, 0.0, cfg.mass_kg * cfg.gravity_mps2])
    if abs(np.linalg.det(a)) < 1e-9:
        return Statics((math.nan, math.nan), math.nan, False, "degenerate", tilt)
    t1, t2, n = np.linalg.solve(a, weight)
    reason = ""
    if min(t1, t2) < cfg.t_min_n:
        reason = "slack"
    elif max(t1, t2) > cfg.t_max_n:
        reason = "over-tension"
    elif n < 0.0:
        reason = "off the face"
    return Statics((float(t1), float(t2)), float(n), reason == "", reason, tilt)


def tether_state(z: ZMap, grid: MapGrid, anchors: F64, xy: F64, cfg: TetherConfig,
                 footprint_m: float = 0.3) -> TetherState | None:
    iy, ix, inside = grid.cell_index(np.array([xy[0]]), np.array([xy[1]]))
    if not inside[0]:
        return None
    zg = height_at(z, grid, xy)
    normal = surface_normal(z, grid, xy, footprint_m)
    if not math.isfinite(zg) or normal is None:
        return None
    bot = np.array([xy[0], xy[1], zg]) + cfg.attach_m * normal
    p1 = tether_path(z, grid, anchors[0], bot, cfg)
    p2 = tether_path(z, grid, anchors[1], bot, cfg)
    return TetherState((p1, p2), reference_statics(p1.pull, p2.pull, normal, cfg))


def settle(z: ZMap, grid: MapGrid, anchors: F64, lengths: tuple[float, float], guess_xy: F64,
           cfg: TetherConfig, iterations: int = 30, tol_m: float = 1e-3) -> tuple[F64, TetherState] | None:
    from fsw.core.team.tether_settle import _settle_search

    xy = np.asarray(guess_xy, float).copy()
    h = grid.cell
    target = np.asarray(lengths, float)
    accept = 10 * tol_m + 0.25 * h
    best: tuple[float, F64] = (math.inf, xy.copy())
    for _ in range(iterations):
        st = tether_state(z, grid, anchors, xy, cfg)
        if st is None:
            return None
        r = np.asarray(st.lengths_m) - target
        if float(np.max(np.abs(r))) < best[0]:
            best = (float(np.max(np.abs(r))), xy.copy())
        if np.max(np.abs(r)) < tol_m:
            return xy, st
        jac = np.empty((2, 2))
        for k in range(2):
            e = np.zeros(2)
            e[k] = h
            hi = tether_state(z, grid, anchors, xy + e, cfg)
            lo = tether_state(z, grid, anchors, xy - e, cfg)
            if hi is None or lo is None:
                return None
            jac[:, k] = (np.asarray(hi.lengths_m) - np.asarray(lo.lengths_m)) / (2 * h)
        if abs(np.linalg.det(jac)) < 1e-9:
            return None
        step = np.linalg.solve(jac, r)
        n = float(np.linalg.norm(step))
        if n > 0.5:
            step *= 0.5 / n
        r_norm = float(np.linalg.norm(r))
        for _ in range(6):
            trial = tether_state(z, grid, anchors, xy - step, cfg)
            if trial is not None and float(np.linalg.norm(np.asarray(trial.lengths_m) - target)) < r_norm:
                break
            step = 0.5 * step
        xy = xy - step
    st = tether_state(z, grid, anchors, xy, cfg)
    if st is not None and np.max(np.abs(np.asarray(st.lengths_m) - target)) < accept:
        return xy, st
    return _settle_search(z, grid, anchors, target, best[1], cfg, accept)
