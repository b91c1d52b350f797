"""The face map judged against the truth (docs/algorithm.md §8.1; ``safer-hil experiment face-map``).

* :func:`truth_along_normal`: for each face cell, the truth surface on the line through the cell
  centre along the face normal: the outermost crossing ``w`` (from inside the ground to the air)
  and whether the line crosses the surface more than once over more than the overhang gap (a
  truth overhang: two surfaces over one spot of the face).
* :func:`face_figures`: the figures a team mission puts in its summary (``team.face_rmse_m``,
  ``team.face_rmse_gravity_m``), at the same face points: the true surface's crossing of the
  normal through each mapped, single-surface face cell's centre. Each map is queried there in
  its own coordinates, as a user queries it, and its error is the distance from the point it
  returns to the true point: the face map at ``(u, v)`` returns ``w`` (error along the normal),
  the gravity grid at ``(x, y)`` returns its cell's ``z`` (error along the vertical: one 3 cm
  cell on a 75 deg face holds 11 cm of face height). ``face_rmse_gravity_normal_m`` adds the
  gravity grid's distance from the true surface along the same normal (where the normal
  crosses its heightfield of one height per cell), the error a grid's staircase keeps when it
  is read in the face's own direction.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fsw.core.map.elevation_map import ElevationMap
from fsw.core.map.face_map import FaceMap
from fsw.core.map.free_space import air_under
from hil_sim.world.world import World

F64 = NDArray[np.float64]
B = NDArray[np.bool_]


def along_normal(height: Callable[[F64, F64], F64], face: FaceMap, cells: NDArray[np.intp],
                 reach_m: float = 0.25, step_m: float = 0.005, chunk: int = 4000,
                 offset: tuple[float, float] = (0.0, 0.0)) -> tuple[F64, B]:
    """``(w, overhang)``: where the line through each face cell's centre (flat indices ``cells``)
    along the face normal leaves the heightfield ``height(x, y)`` for the last time (from below
    the surface to above it; NaN where it does not inside the face map's slab grown by
    ``reach_m``, or where ``height`` is NaN there), and whether it crosses the surface more than
    once over more than the overhang gap; ``offset``: the line moved from the centre by that
    ``(du, dv)``."""
    g = face.grid
    ws = np.arange(-face.cfg.slab_in_m - reach_m, face.cfg.slab_out_m + reach_m + step_m / 2, step_m)
    out_w = np.full(len(cells), np.nan)
    out_o = np.zeros(len(cells), bool)
    gap = face.cfg.overhang_gap_m
    for a in range(0, len(cells), chunk):
        c = cells[a:a + chunk]
        u = g.x0 + (c % g.nx + 0.5) * g.cell + offset[0]
        v = g.y0 + (c // g.nx + 0.5) * g.cell + offset[1]
        q = np.stack(np.broadcast_arrays(u[:, None], v[:, None], ws[None, :]), axis=-1)
        p = face.frame.to_world(q.reshape(-1, 3)).reshape(q.shape)
        f = p[..., 2] - height(p[..., 0], p[..., 1])
        known = np.isfinite(f)
        air = f > 0
        pair = known[:, :-1] & known[:, 1:]
        up = pair & ~air[:, :-1] & air[:, 1:]  # below -> above between samples k and k + 1
        down = pair & air[:, :-1] & ~air[:, 1:]
        has = up.any(axis=1)
        last = np.where(has, up.shape[1] - 1 - np.argmax(up[:, ::-1], axis=1), 0)
        first = np.argmax(up | down, axis=1)
        r = np.arange(len(c))
        f0, f1 = f[r, last], f[r, last + 1]
        with np.errstate(invalid="ignore", divide="ignore"):
            t = np.clip(np.nan_to_num(-f0 / (f1 - f0)), 0.0, 1.0)
        out_w[a:a + chunk] = np.where(has, ws[last] + t * step_m, np.nan)
        crossings = (up | down).sum(axis=1)
        out_o[a:a + chunk] = has & (crossings > 1) & ((last - first) * step_m > gap)
    return out_w, out_o


def air_along_normal(world: World, face: FaceMap, cells: NDArray[np.intp], reach_m: float = 0.25,
                     step_m: float = 0.005) -> tuple[F64, NDArray[np.bool_]]:
    """Samples ``step_m`` apart along the face normal through each face cell's centre, from
    ``reach_m`` inside the face map's slab to ``reach_m`` outside it: their offsets along the
    normal (m), and per cell and sample whether it lies in the air above the true ground."""
    g = face.grid
    ws = np.arange(-face.cfg.slab_in_m - reach_m, face.cfg.slab_out_m + reach_m + step_m / 2, step_m)
    u = g.x0 + (cells % g.nx + 0.5) * g.cell
    v = g.y0 + (cells // g.nx + 0.5) * g.cell
    q = np.stack(np.broadcast_arrays(u[:, None], v[:, None], ws[None, :]), axis=-1)
    p = face.frame.to_world(q.reshape(-1, 3)).reshape(q.shape)
    return ws, p[..., 2] - np.nan_to_num(world.ground_at(p[..., 0], p[..., 1]), nan=1e9) > 0


def air_gap_along_normal(world: World, face: FaceMap, cells: NDArray[np.intp], reach_m: float = 0.25,
                         step_m: float = 0.005) -> F64:
    """The widest run of air between the first and the last crossing of the true surface on the
    line through each face cell's centre along the face normal (0: one crossing). A truth overhang
    (:func:`along_normal`: first and last crossing more than the gap apart) may hold only a sliver
    of air between its two surfaces (a rock resting on the face); one whose air is as wide as the
    gap is two surfaces a view can tell apart."""
    _, air = air_along_normal(world, face, cells, reach_m, step_m)
    out = np.zeros(len(cells))
    for k in range(len(cells)):
        a = air[k]
        up = np.flatnonzero(~a[:-1] & a[1:])
        if len(up) < 2:
            continue
        inner = a[up[0] + 1:up[-1] + 1]  # from the first up-crossing to the last one
        edges = np.flatnonzero(np.diff(np.concatenate([[0], inner.astype(np.int8), [0]])))
        out[k] = float((edges[1::2] - edges[::2]).max()) * step_m if len(edges) else 0.0
    return out


def truth_along_normal(world: World, face: FaceMap, cells: NDArray[np.intp]) -> tuple[F64, B]:
    """:func:`along_normal` of the true ground (``(w_true, overhang)``)."""
    return along_normal(lambda x, y: np.nan_to_num(world.ground_at(x, y), nan=1e9), face, cells)


def overhang_in_cell(world: World, face: FaceMap, cells: NDArray[np.intp]) -> B:
    """Whether the true ground holds two surfaces (:func:`along_normal`) on the normal through
    any of the four quarter-centres of each cell (``cells``): a cell an overhang covers in part,
    though not at its centre (where the truth judges it)."""
    q = 0.25 * face.grid.cell
    out = np.zeros(len(cells), bool)
    for du, dv in ((-q, -q), (-q, q), (q, -q), (q, q)):
        out |= along_normal(lambda x, y: np.nan_to_num(world.ground_at(x, y), nan=1e9), face, cells,
                            offset=(du, dv))[1]
    return out


def gravity_along_normal(gravity: ElevationMap, face: FaceMap, cells: NDArray[np.intp]) -> F64:
    """The gravity grid read along the face normal: :func:`along_normal` of its heightfield
    (one height per cell, as the grid is used; NaN where the crossing meets an unknown cell)."""
    g = gravity.grid

    def height(x: F64, y: F64) -> F64:
        iy, ix, inside = g.cell_index(x, y)
        z = gravity.z[np.clip(iy, 0, g.ny - 1), np.clip(ix, 0, g.nx - 1)]
        return np.where(inside, z, np.nan)

    return along_normal(height, face, cells)[0]


def overhang_seen(face: FaceMap, cells: NDArray[np.intp], w_true: F64, over: B,
                  rays: list[tuple[F64, F64]]) -> B:
    """Which truth overhang cells (``over``, outer surface ``w_true``) some view could show as
    one: a true sight line (``rays``: true camera centre and the true surface points it sees,
    world) crosses the cell's column more than the overhang gap below the outer surface, in the
    air between the two surfaces or ending on the inner one. A cell no sight line reaches under
    its outer surface looks from every view like a single surface."""
    g = face.grid
    z = np.full(g.nx * g.ny, np.nan)
    z[cells[over]] = w_true[over]
    total = np.zeros(g.nx * g.ny, np.int64)
    reach = (-face.cfg.slab_in_m, face.cfg.slab_out_m)
    for eye, pts in rays:
        q = face.frame.to_face(pts)
        n = len(q)
        r, _ = air_under(g, z, np.zeros_like(z), face.frame.to_face(np.reshape(eye, (1, 3)))[0], q,
                         np.zeros(n), np.full(n, 1e-3), reach, face.cfg.overhang_gap_m, 0.0, 0.25 * g.cell)
        total += r
    return np.asarray(over & (total[cells] > 0), bool)


def facing_seen(world: World, face: FaceMap, rays: list[tuple[F64, F64]], step_m: float = 0.01) -> B:
    """Per face cell (flat), whether some view's true sight lines (``rays``: true camera centre and
    the true surface points it sees, world) end in the cell on ground that faces the face: the true
    surface's normal there (from the heightfield's slope over ``step_m``) has a negative component
    along the face normal, so going out along the normal the column passes from air into ground
    (a second surface above it). What a view shows, before stereo: the face map's own facing test
    (``fsw.core.map.overhang``) sees it only where the view's points resolve that ground's plane."""
    g = face.grid
    out = np.zeros(g.nx * g.ny, bool)
    e_n = face.frame.normal
    for _, pts in rays:
        if len(pts) == 0:
            continue
        q = face.frame.to_face(pts)
        iy, ix, inside = g.cell_index(q[:, 0], q[:, 1])
        c = iy[inside] * g.nx + ix[inside]
        x, y = pts[inside, 0], pts[inside, 1]
        zx = (world.ground_at(x + step_m, y) - world.ground_at(x - step_m, y)) / (2 * step_m)
        zy = (world.ground_at(x, y + step_m) - world.ground_at(x, y - step_m)) / (2 * step_m)
        with np.errstate(invalid="ignore"):
            down = (-zx * e_n[0] - zy * e_n[1] + e_n[2]) < 0  # (-z_x, -z_y, 1) . e_n
        out[c[down]] = True
    return out


def overhang_shown(world: World, face: FaceMap, cells: NDArray[np.intp], w_true: F64, over: B,
                   rays: list[tuple[F64, F64]], step_m: float = 0.01) -> B:
    """Which truth overhang cells (``over``, outer surface ``w_true``) the views show as two
    surfaces, from their true sight lines (``rays``: true camera centre and the true surface
    points it sees, world): some view sees a point in the cell's column on ground that faces the
    face (:func:`facing_seen`), or the views show air and ground above it in the column more than
    the gap apart (a sight line crosses the column more than the gap below the outer surface,
    :func:`overhang_seen`, and some view sees a point in the column more than the gap above the
    lowest such crossing). A cell no view shows so is one surface to every view: its second
    surface is not observable."""
    g = face.grid
    size = g.nx * g.ny
    z = np.full(size, np.nan)
    z[cells[over]] = w_true[over]
    lowest = np.full(size, np.inf)
    top = np.full(size, -np.inf)
    reach = (-face.cfg.slab_in_m, face.cfg.slab_out_m)
    for eye, pts in rays:
        if len(pts) == 0:
            continue
        q = face.frame.to_face(pts)
        n = len(q)
        _, low = air_under(g, z, np.zeros_like(z), face.frame.to_face(np.reshape(eye, (1, 3)))[0], q,
                           np.zeros(n), np.full(n, 1e-3), reach, face.cfg.overhang_gap_m, 0.0, 0.25 * g.cell)
        lowest = np.minimum(lowest, low)
        iy, ix, inside = g.cell_index(q[:, 0], q[:, 1])
        np.maximum.at(top, iy[inside] * g.nx + ix[inside], q[inside, 2])
    shown = facing_seen(world, face, rays, step_m) | (top - lowest > face.cfg.overhang_gap_m)
    return np.asarray(over & shown[cells], bool)


def frame_off_deg(world: World, face: FaceMap) -> float | None:
    """The angle between the face map's fitted normal and the scenario's nominal face normal
    (the face falls toward -y at ``team.face_slope_deg``; the edge's wiggle turns the true face
    locally by some degrees either way). None without a team. A frame tens of degrees off is a
    plane fitted to something other than the face (a rock jumble's sides): along its normal the
    face's ordinary relief crosses a cell's column more than once."""
    t = world.team
    if t is None:
        return None
    a = math.radians(t.face_slope_deg)
    return _angle_deg(face.frame.normal, np.array([0.0, -math.sin(a), math.cos(a)]))


def _angle_deg(a: F64, b: F64) -> float:
    """The angle between the unit vectors ``a`` and ``b``, degrees."""
    return float(np.degrees(np.arccos(np.clip(float(a @ b), -1.0, 1.0))))


def true_face_normal(world: World, step_m: float = 0.04, margin_m: float = 0.1) -> F64 | None:
    """The normal (``e_n . z > 0``) of the total least-squares plane of the true face: the
    ground on a ``step_m`` lattice over the world's width, from ``margin_m`` below the plateau
    to ``margin_m`` above the floor and above the face's foot in each column (the floor's rocks
    left out), the rock jumble (grown by 0.3 m) left out, each sample weighted by the area of
    surface it stands for (a lattice over the ground samples a wall more sparsely than a
    ledge). A face broken by ledges falls less steeply, lip to foot, than ``team.face_slope_deg``
    between its ledges; this is the plane a fit to the whole face should find. None without a
    team or a face."""
    t = world.team
    if t is None:
        return None
    x0, x1, y0, y1 = world.extent
    xs = np.arange(x0 + step_m / 2, x1, step_m)
    ys = np.arange(y0 + step_m / 2, y1, step_m)
    px, py = np.meshgrid(xs, ys)
    pz = world.ground_at(px, py)
    floor = pz <= -t.drop_m + 0.05
    # the face's foot per column: the highest y at which the floor is reached
    foot = np.where(floor.any(axis=0), np.max(np.where(floor, py, -np.inf), axis=0), -np.inf)
    jx, jy, jax, jay = t.jumble_xy_r
    jumble = ((px - jx) / (jax + 0.3)) ** 2 + ((py - jy) / (jay + 0.3)) ** 2 < 1.0
    with np.errstate(invalid="ignore"):
        sel = (pz < world.plateau_z - margin_m) & (pz > -t.drop_m + margin_m) & (py > foot[None, :])
        sel &= ~jumble & np.isfinite(pz)
    if int(sel.sum()) < 3:
        return None
    gy, gx = np.gradient(pz, step_m)
    area = np.sqrt(1.0 + gx[sel] ** 2 + gy[sel] ** 2)  # each sample's share of the surface, not of the lattice
    area = np.where(np.isfinite(area), area, 1.0)
    p = np.column_stack([px[sel], py[sel], pz[sel]])
    c = (area[:, None] * p).sum(axis=0) / area.sum()
    _, _, vt = np.linalg.svd(np.sqrt(area)[:, None] * (p - c), full_matrices=False)
    return np.asarray(vt[2] if vt[2][2] >= 0 else -vt[2], float)


def frame_off_true_deg(world: World, face: FaceMap) -> float | None:
    """The angle between the face map's fitted normal and the true face's plane
    (:func:`true_face_normal`); None without one."""
    n = true_face_normal(world)
    return None if n is None else _angle_deg(face.frame.normal, n)


def face_points(face: FaceMap, cells: NDArray[np.intp], w: F64) -> F64:
    """World points ``(N, 3)`` at ``w`` on the normal through each face cell's centre."""
    g = face.grid
    u = g.x0 + (cells % g.nx + 0.5) * g.cell
    v = g.y0 + (cells // g.nx + 0.5) * g.cell
    return face.frame.to_world(np.column_stack([u, v, w]))


def gravity_at_points(gravity: ElevationMap, face: FaceMap, cells: NDArray[np.intp], w_true: F64) -> F64:
    """The gravity grid's error at the true face points (``w_true`` on each cell's normal): its
    cell's ``z`` at the point's ``(x, y)`` less the point's ``z`` (NaN: unknown cell, no point)."""
    p = face_points(face, cells, np.nan_to_num(w_true))
    g = gravity.grid
    iy, ix, inside = g.cell_index(p[:, 0], p[:, 1])
    z = gravity.z[np.clip(iy, 0, g.ny - 1), np.clip(ix, 0, g.nx - 1)]
    return np.where(inside & np.isfinite(w_true), z - p[:, 2], np.nan)


def _rms(e: F64) -> float | None:
    e = e[np.isfinite(e)]
    return float(np.sqrt(np.mean(e * e))) if e.size else None


def face_figures(world: World, face: FaceMap, gravity: ElevationMap,
                 cells_by_agent: dict[str, int] | None = None,
                 rays: list[tuple[F64, F64]] | None = None) -> dict[str, Any]:
    """The team summary's face figures (module docstring): ``face_rmse_m`` (mapped single-surface
    face cells, the face map), ``face_rmse_gravity_m`` (the same points, queried from
    ``gravity``; only cells both have), ``face_rmse_gravity_normal_m``, ``face_cells``,
    ``overhang_truth``, ``overhang_flagged``, ``overhang_false`` (flags on single-surface cells; of
    them ``overhang_false_part``: an overhang covers part of the cell, :func:`overhang_in_cell`),
    ``overhang_open`` (truth overhangs
    with air as wide as the gap between their surfaces, :func:`air_gap_along_normal`),
    ``overhang_open_flagged`` and ``cells_by_agent``; with the
    views' true sight lines ``rays`` also ``overhang_seen`` (truth overhangs some view could
    show, :func:`overhang_seen`), ``overhang_seen_flagged``, ``overhang_shown`` (those the views
    show as two surfaces, :func:`overhang_shown`) and ``overhang_shown_flagged``."""
    cells = np.flatnonzero(face.map.mapped.reshape(-1))
    w_true, over = truth_along_normal(world, face, cells)
    e_face = face.map.z.reshape(-1)[cells] - w_true
    e_grav = gravity_at_points(gravity, face, cells, w_true)
    e_norm = gravity_along_normal(gravity, face, cells) - w_true
    both = ~over & np.isfinite(e_face) & np.isfinite(e_grav)
    flagged = face.overhang.reshape(-1)[cells]
    seen = overhang_seen(face, cells, w_true, over, rays) if rays is not None else None
    shown = overhang_shown(world, face, cells, w_true, over, rays) if rays is not None else None
    false = flagged & ~over
    beside = np.zeros(len(cells), bool)
    beside[false] = overhang_in_cell(world, face, cells[false])
    open_air = np.zeros(len(cells), bool)
    open_air[over] = air_gap_along_normal(world, face, cells[over]) >= face.cfg.overhang_gap_m
    return {
        "overhang_open": int(open_air.sum()), "overhang_open_flagged": int((open_air & flagged).sum()),
        "overhang_seen": None if seen is None else int(seen.sum()),
        "overhang_seen_flagged": None if seen is None else int((seen & flagged).sum()),
        "overhang_shown": None if shown is None else int(shown.sum()),
        "overhang_shown_flagged": None if shown is None else int((shown & flagged).sum()),
        "face_rmse_m": _rms(e_face[both]), "face_rmse_gravity_m": _rms(e_grav[both]),
        "face_rmse_gravity_normal_m": _rms(e_norm[both]),
        "face_cells": int(both.sum()), "overhang_truth": int(over.sum()),
        "overhang_flagged": int((over & flagged).sum()), "overhang_false": int(false.sum()),
        "overhang_false_part": int(beside.sum()),
        "cells_by_agent": dict(cells_by_agent or {}),
    }


def relief_rise(world: World, face: FaceMap, reach: int = 2) -> F64:
    """Per face cell (flat), how far the true surface rises out of the face (along the normal,
    at the cell centres) within ``reach`` cells of it, above its own height: the step a view at
    grazing incidence sees in front of, or beside, the cell (NaN where the truth has no single
    surface anywhere in reach)."""
    g = face.grid
    w, over = truth_along_normal(world, face, np.arange(g.nx * g.ny))
    W = np.where(over | ~np.isfinite(w), np.nan, w).reshape(g.shape)
    pad = np.pad(W, reach, constant_values=np.nan)
    near = np.stack([pad[reach + dy: reach + dy + g.ny, reach + dx: reach + dx + g.nx]
                     for dy in range(-reach, reach + 1) for dx in range(-reach, reach + 1)])
    top = np.full(g.shape, np.nan)
    seen = np.isfinite(near).any(axis=0)
    top[seen] = np.nanmax(near[:, seen], axis=0)
    return np.asarray((top - W).reshape(-1), float)
