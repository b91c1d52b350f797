"""Overhangs in the face map: cells with more than one surface along the face normal (docs/algorithm.md §8.1).

A face map (``fsw.core.map.face_map``) holds one height ``w`` per ``(u, v)`` cell. Where the
ground crosses the cell's normal more than once (a rock's outer side over the face in the
crevice behind it) the cell is flagged (:attr:`Overhangs.overhang`), not averaged:

* within a view (:meth:`Overhangs.two_surfaces`): its points in a cell split at a gap in ``w``
  wider than ``overhang_gap_m`` and both parts fall in one of the cell's 2x2 sub-cells (a step
  inside a cell puts its two levels side by side, an overhang over the same spot). The outer
  surface (the larger ``w``, what the normal sees from outside) is fused and the inner one goes
  to :attr:`Overhangs.second`;
* across views: a view's measurement lies more than ``overhang_gap_m`` plus the gate from the
  cell's fused height; the cell keeps the better-supported surface and the other goes to
  :attr:`Overhangs.second`;
* free space (:meth:`Overhangs.carve`, given the camera centre): rays that pass under a cell's
  surface (``fsw.core.map.free_space``), or a camera standing under the cell's tangent plane
  (it sees the surface's lower side), show air under ground, so a second surface even where no
  view saw one;
* a surface facing the face (:meth:`Overhangs.facing`, given the camera centre): a view's
  points whose local plane (fitted to the view's own points around each in the point's noise,
  :func:`facing_cones`, its normal turned to the camera) faces the face (``e_n`` component below
  ``-sin facing_deg`` at ``facing_sigma`` sigma of the fit either way) lie where the normal,
  going out, passes from air into ground: the ground above them along the normal ends in air
  again (the face map's slab ends in air), so their column holds two surfaces. It is the rock's
  side that faces up the face, seen from above, over the crevice behind it; it needs no fused
  height (the tests above compare with the cell's height, which may be either surface);
* beside a flag (:meth:`Overhangs.beside_flags`): a cell next to a flagged one with fewer facing
  points than the facing test needs (``facing_beside_points``, one by default) is flagged: the
  overhang's surfaces run on past the cell where a view counted enough of its facing ground
  (a view resolves a rock's facing side at a few points of a cell near its edge, where the
  local plane's neighbours straddle the edge and no plane is fitted).

Each flag keeps the test that set it first (:attr:`Overhangs.flagged_by`, an index into
:data:`FLAG_TESTS`): what the flag rests on, for an operator judging it and for the face-map
experiment sorting its false flags.

The tests read their parameters from the face map's (:class:`OverhangParams`, from
``FaceMapConfig``) and the face map's grid (``emap``); all coordinates are the face
frame's ``(u, v, w)``.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage
from scipy.spatial import cKDTree

from fsw.core.geometry import MapGrid
from fsw.core.map.elevation_map import ElevationMap
from fsw.core.map.free_space import air_under

F64 = NDArray[np.float64]
B = NDArray[np.bool_]

_PLANE_POINTS = 8  # points a local plane is fitted to, at least
_EDGE_ON = float(np.sin(np.radians(5.0)))  # a sight line closer to its plane sees it edge-on
_PLANE_NEIGHBOURS = 32  # nearest points looked at, at most
_NOISE_FLOOR = 1e-3  # m: the least error a point is taken to have along any axis (the fit's whitening)


class OverhangParams(Protocol):
    """The overhang tests' parameters (``fsw.core.map.face_map.FaceMapConfig``)."""

    @property
    def overhang_gap_m(self) -> float: ...
    @property
    def air_min_rays(self) -> int: ...
    @property
    def air_sigma(self) -> float: ...
    @property
    def underside_deg(self) -> float: ...
    @property
    def air_max_rays(self) -> int: ...
    @property
    def slab_in_m(self) -> float: ...
    @property
    def slab_out_m(self) -> float: ...
    @property
    def facing_deg(self) -> float: ...
    @property
    def facing_radius_m(self) -> float: ...
    @property
    def facing_min_points(self) -> int: ...
    @property
    def facing_max_points(self) -> int: ...
    @property
    def facing_beside_points(self) -> int: ...
    @property
    def facing_sigma(self) -> float: ...


FLAG_TESTS = ("", "within_view", "across_views", "free_space", "underside", "facing", "beside_flag")
"""The tests that flag a cell (module docstring), by their code in :attr:`Overhangs.flagged_by`
(0: not flagged): two surfaces within one view's points, a view's surface beyond the cell's by
more than the gap, rays under the surface, a camera under its tangent plane, ground facing the
face, facing ground beside a flag."""


class Overhangs:
    """The overhang layers of a face map grid of ``shape`` and the tests that set them."""

    def __init__(self, shape: tuple[int, int]) -> None:
        self.overhang = np.zeros(shape, bool)
        # the test that flagged each cell first (its index in FLAG_TESTS; 0 not flagged): what a
        # flag rests on, for the operators judging it and the experiments sorting false flags
        self.flagged_by = np.zeros(shape, np.int8)
        self.second = np.full(shape, np.nan)  # the other surface's w where flagged
        self.air = np.zeros(shape, np.int32)  # rays that passed under the surface
        self.air_w = np.full(shape, np.nan)  # the lowest w they reached (inner surface below)
        self.under = np.full(shape, np.nan)  # sine of the deepest view under the tangent plane
        self.facing = np.zeros(shape, np.int32)  # view points on a surface that faces the face

    def flag(self, cells: B, test: str) -> int:
        """Flag ``cells`` (a mask of the grid, flat or not) by ``test`` (of :data:`FLAG_TESTS`);
        the cells already flagged keep their first test. Returns the cells newly flagged."""
        new = np.asarray(cells, bool).reshape(self.overhang.shape) & ~self.overhang
        self.flagged_by[new] = FLAG_TESTS.index(test)
        self.overhang |= new
        return int(new.sum())

    def carve(self, emap: ElevationMap, cfg: OverhangParams, eye: F64, q: F64, cov_f: F64) -> int:
        """The free-space tests of one view, after its merge into ``emap``: the rays from the
        camera centre ``eye`` to the points ``q`` (both in the face frame; ``cov_f`` the points'
        covariances there), each cut short of its point by ``air_sigma`` times the root of its
        covariance's trace and one cell. A cell is flagged when ``air_min_rays`` rays (of this
        view and earlier ones) passed under its surface by more than the gap plus ``air_sigma``
        sigma (:attr:`air`, :attr:`air_w`), or when a view with a point in it stood more than
        ``underside_deg`` under its tangent plane (:attr:`under`). Returns the cells newly
        flagged."""
        grid = emap.grid
        var_w = np.maximum(cov_f[:, 2, 2], 0.0)
        # cut short of the point: its error along any direction and one cell
        stop = cfg.air_sigma * np.sqrt(np.maximum(np.trace(cov_f, axis1=1, axis2=2), 0.0)) + grid.cell
        rays, lowest = air_under(grid, emap.z, emap.var, eye, q, var_w, stop, (-cfg.slab_in_m, cfg.slab_out_m),
                                 cfg.overhang_gap_m, cfg.air_sigma, 0.5 * grid.cell)
        air, air_w = self.air.reshape(-1), self.air_w.reshape(-1)
        air += rays.astype(np.int32)
        hit = np.isfinite(lowest)
        air_w[hit] = np.fmin(air_w[hit], lowest[hit])
        if cfg.underside_deg > 0:
            self.under = np.fmax(self.under, seen_from_below(emap, eye, q))
        new = self.flag(air >= cfg.air_min_rays, "free_space")
        if cfg.underside_deg > 0:
            new += self.flag(self.under > np.sin(np.radians(cfg.underside_deg)), "underside")
        return new

    def facing_the_face(self, grid: MapGrid, cfg: OverhangParams, eye: F64, q: F64,
                        noise: F64) -> tuple[B, int]:
        """The facing test of one view (module docstring): its points ``q`` (their covariances
        without the view's common part ``noise``) and camera centre ``eye`` in the face frame, at
        most ``facing_max_points`` of the points (evenly spread), each with the plane of the
        view's points within ``facing_radius_m`` of it fitted in the point's noise
        (:func:`facing_cones`). A cell is flagged when ``facing_min_points`` points in it (of
        this view and earlier ones) lie on a plane whose normal, turned to the camera, has an
        ``e_n`` component below ``-sin(facing_deg)`` at ``facing_sigma`` sigma of the fit either
        way, and which the camera sees more than 5 deg off edge-on (a plane seen edge-on has no
        side) (:attr:`facing`). Returns which points of ``q`` were found on such a plane (they lie
        on the inner side of the ground along the normal: the caller keeps them out of the cell's
        height, and their mean ``w`` becomes the cell's :attr:`second` where none is known) and
        the cells newly flagged."""
        out = np.zeros(len(q), bool)
        fin = np.flatnonzero(np.isfinite(q).all(axis=1) & np.isfinite(noise).all(axis=(1, 2)))
        if cfg.facing_max_points == 0 or len(fin) < _PLANE_POINTS:
            return out, 0
        q = q[fin]
        sel = np.unique(np.linspace(0, len(q) - 1, min(len(q), cfg.facing_max_points)).astype(np.intp))
        cone, ok = facing_cones(q, q[sel], noise[fin[sel]], cfg.facing_radius_m, cfg.facing_sigma)
        sight = np.asarray(eye, float).reshape(1, 3) - q[sel]
        sight /= np.maximum(np.linalg.norm(sight, axis=1, keepdims=True), 1e-9)
        side = np.einsum("ij,icj->ic", sight, cone)
        n_w = np.where(side < 0, -cone[:, :, 2], cone[:, :, 2])  # each normal turned to the camera
        s_min = np.sin(np.radians(cfg.facing_deg))
        # facing the face however the fit errs, and seen clearly from one side (edge-on: no side)
        hit = ok & (n_w < -s_min).all(axis=1) & (np.abs(side[:, 0]) > _EDGE_ON)
        iy, ix, inside = grid.cell_index(q[sel, 0], q[sel, 1])
        hit &= inside
        size = grid.nx * grid.ny
        c = iy[hit] * grid.nx + ix[hit]
        flat = self.facing.reshape(-1)
        flat += np.bincount(c, minlength=size).astype(np.int32)
        with np.errstate(invalid="ignore", divide="ignore"):
            mean = np.bincount(c, q[sel[hit], 2], size) / np.bincount(c, minlength=size)
        second = self.second.reshape(-1)
        second[:] = np.where(np.isnan(second), mean, second)
        new = self.flag(self.facing >= cfg.facing_min_points, "facing")
        out[fin[sel[hit]]] = True
        return out, new

    def beside_flags(self, cfg: OverhangParams) -> int:
        """The facing test beside a flag (module docstring): a cell holding ``facing_beside_points``
        points on planes facing the face (fewer than ``facing_min_points``), next to a flagged cell
        (of its eight neighbours), is flagged. An overhang's inner and outer surfaces run on past
        the cell where a view counted enough of the facing ground between them; one such point
        beside them is that ground seen in part. Run once per view, after its tests (a flag
        spreads one cell per view at most). Returns the cells newly flagged."""
        if cfg.facing_beside_points <= 0:
            return 0
        near = ndimage.binary_dilation(self.overhang, structure=np.ones((3, 3), bool))
        return self.flag(near & (self.facing >= cfg.facing_beside_points), "beside_flag")

    def two_surfaces(self, emap: ElevationMap, gap: float, q: F64, var_w: F64,
                     min_points: int = 3) -> tuple[B, int, int]:
        """The overhang test of one view (face coordinates ``q``, their variances along the
        normal ``var_w``) against ``emap`` before the view's merge: flags cells, records their
        second surface, and returns which points to fuse, the number of newly flagged cells and
        the points held back. Within the view, each part must hold ``min_points`` points over the
        shared sub-cell; across views, the view's cell mean (of at least ``min_points`` points)
        must lie beyond the gap plus the gate (``gate_sigma`` times the root of the cell's
        variance plus the points' mean variance)."""
        g, m = emap.grid, emap
        n = len(q)
        size = g.nx * g.ny
        keep = np.ones(n, bool)
        if n == 0:
            return keep, 0, 0
        fu = (q[:, 0] - g.x0) / g.cell
        fv = (q[:, 1] - g.y0) / g.cell
        inside = (fu >= 0) & (fu < g.nx) & (fv >= 0) & (fv < g.ny) & np.isfinite(q[:, 2])
        idx = np.flatnonzero(inside)
        cell = fv[idx].astype(np.intp) * g.nx + fu[idx].astype(np.intp)
        sub = (2 * (fv[idx] % 1.0)).astype(np.intp) * 2 + (2 * (fu[idx] % 1.0)).astype(np.intp)
        w = q[idx, 2]
        order = np.lexsort((w, cell))
        cs, ws, vs = cell[order], w[order], var_w[idx][order]
        split = np.zeros(len(cs), bool)
        split[1:] = (cs[1:] == cs[:-1]) & (np.diff(ws) > gap)
        # level of each point in its cell (0 lowest); the top level is the outer surface
        start = np.ones(len(cs), bool)
        start[1:] = cs[1:] != cs[:-1]
        lev = np.cumsum(split)
        lev = lev - np.maximum.accumulate(np.where(start, lev, 0))
        top = np.zeros(size, np.int64)
        np.maximum.at(top, cs, lev)
        outer = lev == top[cs]
        key = cs * 4 + sub[order]
        n_out = np.bincount(key, outer, size * 4)
        n_in = np.bincount(key, ~outer, size * 4)
        # per cell: an outer and an inner part over one sub-cell
        two = np.asarray(((n_out >= min_points) & (n_in >= min_points)).reshape(-1, 4).any(axis=1), bool)
        flat_second = self.second.reshape(-1)
        inner_pts = two[cs] & ~outer
        if inner_pts.any():
            sw = np.bincount(cs[inner_pts], ws[inner_pts], size)
            k = np.bincount(cs[inner_pts], minlength=size)
            with np.errstate(invalid="ignore", divide="ignore"):
                mean_inner = sw / k
            flat_second[two] = mean_inner[two]
        new = self.flag(two, "within_view")
        keep[idx[order[inner_pts]]] = False
        # across views: this view's mean in a mapped cell beyond the gap plus the gate: the
        # cell keeps what it holds, the view's surface goes to ``second``
        kept = ~inner_pts
        cnt = np.bincount(cs[kept], minlength=size)
        with np.errstate(invalid="ignore", divide="ignore"):
            mean = np.bincount(cs[kept], ws[kept], size) / cnt
            vmean = np.bincount(cs[kept], vs[kept], size) / cnt
        zf, vf, mapped = m.z.reshape(-1), m.var.reshape(-1), m.mapped.reshape(-1)
        with np.errstate(invalid="ignore"):
            far = (cnt >= min_points) & mapped & (
                np.abs(mean - zf) > gap + m.cfg.gate_sigma * np.sqrt(vf + vmean))
        # the better-supported surface holds the cell (the gate of FaceElevation swaps them)
        better = far & (vmean < vf)
        flat_second[far & ~better] = mean[far & ~better]
        flat_second[better] = zf[better]
        new += self.flag(far, "across_views")
        keep[idx[order[kept & (far & ~better)[cs]]]] = False
        return keep, new, int(n - keep.sum())


def facing_cones(pts: F64, at: F64, noise: F64, radius_m: float, k_sigma: float) -> tuple[F64, B]:
    """Per query point of ``at`` ``(M, 3)``, the normals ``(M, 5, 3)`` of the plane of the nearest
    of ``pts`` (thinned to one mean per voxel of a quarter of ``radius_m``; at most 32 of those,
    within ``radius_m``) fitted in the query point's noise (``noise`` ``(M, 3, 3)``, its covariance
    without the view's common part), the fitted normal first, then the normals ``k_sigma`` of the
    fit's uncertainty away from it either way about the plane's two axes, and whether there is a
    plane: at least 8 neighbours and its normal known, ``k_sigma`` of it within 45 deg.

    The fit is total least squares after whitening by the noise (the maximum-likelihood plane
    when the neighbours err as the query point does): a stereo point errs mostly along its sight
    line, so a patch seen head-on is thick along its normal and one seen at grazing incidence is
    smeared within its plane; unweighted, either may lose its normal to the smear. In whitened
    units the residual across the plane is 1 when the neighbourhood is a plane within the noise;
    a normal of ``n`` neighbours spread ``s_i`` along axis ``i`` is uncertain about it by
    ``sqrt(r s_i^2 / n) / (s_i^2 - r)`` radians, ``r`` the residual (at least 1; the eigenvector's
    first-order perturbation): a thick neighbourhood (an edge, a corner, a blob of noise) gets a
    wide cone or none, a plane well within the noise a narrow one."""
    key = np.floor(pts / (0.25 * radius_m)).astype(np.int64)
    _, inv, cnt_v = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    inv = inv.reshape(-1)
    points = np.zeros((len(cnt_v), 3))
    np.add.at(points, inv, pts)
    points /= cnt_v[:, None]
    k = min(_PLANE_NEIGHBOURS, len(points))
    dist, idx = cKDTree(points).query(at, k=k, distance_upper_bound=radius_m)
    dist, idx = dist.reshape(len(at), k), idx.reshape(len(at), k)
    near = np.isfinite(dist)
    cnt = near.sum(axis=1)
    nb = points[np.where(near, idx, 0)]  # (M, k, 3); the misses masked below
    wgt = near[..., None].astype(float)
    mean = (nb * wgt).sum(axis=1) / np.maximum(cnt, 1)[:, None]
    d = (nb - mean[:, None, :]) * wgt
    lam, vec_p = np.linalg.eigh(np.asarray(noise, float) + _NOISE_FLOOR**2 * np.eye(3))
    white = np.einsum("mij,mj,mkj->mik", vec_p, 1.0 / np.sqrt(np.maximum(lam, _NOISE_FLOOR**2)), vec_p)
    y = np.einsum("mki,mij->mkj", d, white)  # the offsets in units of the noise
    scatter = np.einsum("mki,mkj->mij", y, y) / np.maximum(cnt, 1)[:, None, None]
    ev, vec = np.linalg.eigh(scatter)  # ascending eigenvalues
    resid = np.maximum(ev[:, 0], 1.0)
    m = vec[:, :, 0]
    cone = [m]
    known = cnt >= _PLANE_POINTS
    for i in (1, 2):
        # the eigenvector's perturbation: sqrt(r s_i^2 / n) / (s_i^2 - r), unbounded as s_i^2 -> r
        over = ev[:, i] - resid
        with np.errstate(divide="ignore", invalid="ignore"):
            tilt = k_sigma * np.sqrt(resid * ev[:, i] / np.maximum(cnt, 1)) / over
        known &= (over > 0) & (tilt < 1.0)
        tilt = np.where(known, tilt, 0.0)
        cone += [m + tilt[:, None] * vec[:, :, i], m - tilt[:, None] * vec[:, :, i]]
    # a plane m . y = c in whitened units is (W m) . x = c: its normal is W m
    normals = np.einsum("mij,mcj->mci", white, np.stack(cone, axis=1))
    normals /= np.maximum(np.linalg.norm(normals, axis=2, keepdims=True), 1e-300)
    return np.asarray(normals, float), np.asarray(known, bool)


def seen_from_below(emap: ElevationMap, eye: F64, q: F64) -> F64:
    """Per cell of ``emap`` holding one of the view's points ``q`` (face frame), the sine of the
    angle by which the camera ``eye`` (face frame) stands under the cell's tangent plane (the
    map's height and gradient there; NaN: no point, or not mapped). A camera under the plane sees
    the surface's lower side: air below it along the normal, ground above."""
    g, m = emap.grid, emap
    iu = np.floor((q[:, 0] - g.x0) / g.cell).astype(np.intp)
    iv = np.floor((q[:, 1] - g.y0) / g.cell).astype(np.intp)
    ok = (iu >= 0) & (iu < g.nx) & (iv >= 0) & (iv < g.ny)
    hit = np.zeros(g.nx * g.ny, bool)
    hit[iv[ok] * g.nx + iu[ok]] = True
    hit &= m.mapped.reshape(-1)
    gv, gu = minmod_gradient(m.z, g.cell)
    c = np.flatnonzero(hit)
    uc = g.x0 + (c % g.nx + 0.5) * g.cell
    vc = g.y0 + (c // g.nx + 0.5) * g.cell
    zc = m.z.reshape(-1)[c]
    a, b = gu.reshape(-1)[c], gv.reshape(-1)[c]
    h = eye[2] - (zc + a * (eye[0] - uc) + b * (eye[1] - vc))
    dist = np.sqrt((eye[0] - uc) ** 2 + (eye[1] - vc) ** 2 + (eye[2] - zc) ** 2)
    sin_el = h / (dist * np.sqrt(1.0 + a * a + b * b))
    out = np.full(g.nx * g.ny, np.nan)
    out[c] = -sin_el
    return out.reshape(g.shape)


def minmod_gradient(z: F64, cell_m: float) -> tuple[F64, F64]:
    """``(d/dv, d/du)`` of a grid's heights by the min-mod of the two one-sided differences per
    axis: the smaller where both have one sign, 0 where they differ or a neighbour is unknown. A
    step between two cells gives neither of them its slope (a central difference would give both
    half of it); a slope spanning several cells keeps it."""
    pad = np.pad(z, 1, constant_values=np.nan)
    c = pad[1:-1, 1:-1]
    out = []
    for p, m in ((pad[2:, 1:-1], pad[:-2, 1:-1]), (pad[1:-1, 2:], pad[1:-1, :-2])):
        fwd, bwd = (p - c) / cell_m, (c - m) / cell_m
        with np.errstate(invalid="ignore"):
            same = np.sign(fwd) == np.sign(bwd)
        g = np.where(same, np.where(np.abs(fwd) < np.abs(bwd), fwd, bwd), 0.0)
        out.append(np.nan_to_num(g, nan=0.0))
    return out[0], out[1]
