"""The face map: a 2.5D grid laid in the plane fitted to a steep face (docs/algorithm.md §8.1).

A gravity-aligned grid samples a face of slope ``a`` at ``1 / cos a`` of its area per cell
(3.9x at 75 deg) and stores the height of a wall. The face map stores the same model (§1: a
height per cell with variance, count, interest, misses) in the face's own frame:

* :class:`~fsw.core.map.face_plane.FaceFrame` is the fitted plane: origin ``o`` and the
  right-handed axes ``e_u`` (along the strike, horizontal), ``e_v`` (up the dip, in the plane)
  and ``e_n`` (the normal, out of the face, ``e_n . z > 0``). A world point ``p`` has face
  coordinates ``q = R^T (p - o)`` with ``R = [e_u e_v e_n]``, its covariance ``R^T P R``.
  :func:`~fsw.core.map.face_plane.fit_face_plane` fits it to the steep cells of a gravity map
  (``fsw.core.map.face_plane``).
* :class:`FaceMap` is an ``ElevationMap`` on a grid over ``(u, v)`` whose height is ``w``, the
  distance along ``e_n``; fusion, the slope term, the gate, misses, the interest function, the
  quadtree reduction and the codec all work on it unchanged (its arrays are a map's arrays).
  That map is a :class:`~fsw.core.map.face_elevation.FaceElevation`, §1.1 with the face's
  changes to a view's variance, weights and gate (``fsw.core.map.face_elevation``). Its band
  along the dip is :func:`~fsw.core.map.face_plane.face_band`.
* The hand-over (:meth:`FaceMap.routes`): a point belongs to the face when its ``(u, v)`` lies
  inside the face map's grid (the band ``[v_min, v_max]`` along the dip) and
  ``-slab_in_m <= w <= slab_out_m`` (rocks stand out of a face; behind it, within half a metre,
  lies only the plateau beyond the edge); otherwise to the gravity grid. In the ``seam_m`` wide
  strips at both ends of the band a point goes to both grids, so each side of the seam is
  mapped up to it. A view that sees a cell's column mostly outside the slab, or comes after views
  that together did, leaves the cell to other views (:meth:`FaceMap.beyond_slab`). A gravity
  cell is *handed to the face* when the fitted plane over its centre lies inside the band minus the seams
  (:meth:`FaceMap.face_owned`); a query at ``(x, y)`` is answered by the face map there
  (:meth:`FaceMap.surface_z`, the vertical line intersected with the face map's surface) and by
  the gravity grid elsewhere (:func:`hand_over_z`).
* Overhangs: a cell with more than one surface along its normal is flagged
  (:attr:`FaceMap.overhang`), not averaged; the tests and their layers live in
  ``fsw.core.map.overhang`` (:class:`~fsw.core.map.overhang.Overhangs`), run on each view by
  :meth:`FaceMap.merge_parts` (before its merge: which points to fuse) and :meth:`FaceMap.carve`
  (after it: free space along the rays).
* The incidence limit (:func:`window_span`; off by default, ``resolve_cells = 0``): a view's
  point whose stereo matching window spans more than ``resolve_cells`` face cells along the face
  (grazing incidence) is not fused into the face map's heights; it still counts for the
  overhang tests and its ray for free space.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from fsw.core.geometry import MapGrid
from fsw.core.map.elevation_map import ElevationMap, FusionConfig, MergeStats
from fsw.core.map.face_elevation import FaceElevation
from fsw.core.map.face_plane import FaceFrame, equal_memory_cell, face_band, fit_face_plane
from fsw.core.map.overhang import Overhangs
from fsw.core.steps import run_to_end
from fsw.framework.params import param

F64 = NDArray[np.float64]
B = NDArray[np.bool_]
ViewPart = tuple[F64, F64, F64 | None]  # world xyz, total covariance, the view's common covariance


@dataclass(frozen=True)
class FaceMapConfig:
    """The face map's parameters (no config section: the benches that build a face map use these defaults)."""

    cell_m: float = param(0.06, lo=0.005, hi=2.0, units="m", doc="face cell side, in the face plane")
    min_slope_deg: float = param(45.0, lo=20.0, hi=89.0, units="deg",
                                 doc="gravity cells steeper than this define the face (fit, band)")
    slab_out_m: float = param(1.5, lo=0.05, hi=20.0, units="m", doc="points farther out of the plane: gravity grid")
    slab_in_m: float = param(0.5, lo=0.05, hi=20.0, units="m", doc="points farther behind the plane: gravity grid")
    seam_m: float = param(0.15, lo=0.0, hi=5.0, units="m", doc="strips at the band's ends that feed both grids")
    overhang_gap_m: float = param(0.10, lo=0.01, hi=5.0, units="m", doc="a gap in w this wide splits two surfaces")
    air_min_rays: int = param(3, lo=1, hi=1000,
                              doc="rays passing under a cell's surface that flag it (free space, overhang)")
    air_sigma: float = param(3.0, lo=0.0, hi=20.0, units="sigma",
                             doc="a ray counts that far (plus the gap) under the surface")
    underside_deg: float = param(20.0, lo=0.0, hi=89.0, units="deg",
                                 doc="a view this far under a cell's tangent plane sees its underside: flag (0: off)")
    air_max_rays: int = param(20000, lo=0, hi=10**7, doc="rays per view traced for free space (0: none)")
    facing_deg: float = param(12.0, lo=0.0, hi=89.0, units="deg",
                              doc="a view's local plane facing the face by this much: a second surface")
    facing_radius_m: float = param(0.06, lo=0.005, hi=1.0, units="m",
                                   doc="neighbours of a point its plane is fitted to")
    facing_min_points: int = param(3, lo=1, hi=10**6, doc="points on planes facing the face that flag a cell")
    facing_max_points: int = param(20000, lo=0, hi=10**7, doc="points per view tested for facing the face (0: none)")
    facing_beside_points: int = param(1, lo=0, hi=10**6,
                                      doc="facing points that flag a cell beside a flagged one (0: off)")
    facing_sigma: float = param(3.0, lo=0.0, hi=20.0, units="sigma",
                                doc="a local plane faces the face at this many sigma of its fit's normal")
    resolve_cells: float = param(0.0, lo=0.0, hi=100.0, units="cells",
                                 doc="a point whose matching window spans more face cells is not fused (0: off)")
    step_cells: int = param(2, lo=0, hi=10, units="cells",
                            doc="a view's cell means this near rising above or falling below a cell's add "
                                "the step's variance to its measurement (0: off)")


@dataclass(frozen=True)
class FaceMergeStats:
    """What one view did to the face map."""

    merge: MergeStats
    overhang_new: int  # cells flagged by this view
    second_points: int  # points kept out of the map as a second surface
    air_new: int = 0  # of those, the cells flagged by free space (rays under the surface, a view from below)
    facing_new: int = 0  # of those, the cells flagged by a surface that faces the face
    grazing: int = 0  # points not fused: their matching window spans more than resolve_cells cells
    beyond_slab: int = 0  # points not fused: the view sees their cell's column mostly outside the slab


class FaceMap:
    """An elevation map (§1) in the face frame: ``map.z`` is ``w`` over the ``(u, v)`` grid."""

    def __init__(self, frame: FaceFrame, u_range: tuple[float, float], v_range: tuple[float, float],
                 cfg: FaceMapConfig | None = None, fusion: FusionConfig | None = None) -> None:
        self.cfg = cfg or FaceMapConfig()
        self.frame = frame
        c = self.cfg.cell_m
        nx = max(2, int(np.ceil((u_range[1] - u_range[0]) / c)))
        ny = max(2, int(np.ceil((v_range[1] - v_range[0]) / c)))
        self.map: ElevationMap = FaceElevation(MapGrid(float(u_range[0]), float(v_range[0]), c, nx, ny), fusion,
                                               self.cfg.step_cells)
        self.overhangs = Overhangs(self.map.grid.shape)  # the overhang layers (fsw.core.map.overhang)
        self._column_counts()

    def _column_counts(self) -> None:
        """Per flat cell, the views' points over it (all views so far) inside the slab and outside
        it (:meth:`beyond_slab`)."""
        size = self.map.grid.nx * self.map.grid.ny
        self.column_in = np.zeros(size, np.int64)
        self.column_out = np.zeros(size, np.int64)

    def empty_like(self) -> FaceMap:
        """An empty face map on the same frame and grid (e.g. one agent's share)."""
        out = FaceMap(self.frame, (0.0, 1.0), (0.0, 1.0), self.cfg, self.map.cfg)
        out.map = FaceElevation(self.map.grid, self.map.cfg, self.cfg.step_cells)
        out.overhangs = Overhangs(self.map.grid.shape)
        out._column_counts()
        return out

    @property
    def overhang(self) -> B:
        """Cells with more than one surface along the normal (flagged, not averaged)."""
        return self.overhangs.overhang

    @property
    def flagged_by(self) -> NDArray[np.int8]:
        """The test that flagged each cell first (``fsw.core.map.overhang.FLAG_TESTS``; 0: not flagged)."""
        return self.overhangs.flagged_by

    @property
    def second(self) -> F64:
        """The other surface's ``w`` where a view saw it (NaN elsewhere)."""
        return self.overhangs.second

    @property
    def air(self) -> NDArray[np.int32]:
        """Rays that passed under each cell's surface."""
        return self.overhangs.air

    @property
    def facing(self) -> NDArray[np.int32]:
        """View points on a surface that faces the face, per cell."""
        return self.overhangs.facing

    @property
    def air_w(self) -> F64:
        """The lowest ``w`` those rays reached (the inner surface lies below it)."""
        return self.overhangs.air_w

    @property
    def grid(self) -> MapGrid:
        return self.map.grid

    @property
    def v_range(self) -> tuple[float, float]:
        g = self.map.grid
        return g.y0, g.y0 + g.ny * g.cell

    @property
    def u_range(self) -> tuple[float, float]:
        g = self.map.grid
        return g.x0, g.x0 + g.nx * g.cell

    # -- the hand-over ------------------------------------------------------------------------
    def routes(self, xyz: F64) -> tuple[B, B]:
        """``(to_face, to_gravity)`` per world point: inside the band and the slab to the face,
        outside to the gravity grid, both in the seam strips."""
        q = self.frame.to_face(xyz)
        v0, v1 = self.v_range
        u0, u1 = self.u_range
        s = self.cfg.seam_m
        with np.errstate(invalid="ignore"):
            slab = (q[:, 2] <= self.cfg.slab_out_m) & (q[:, 2] >= -self.cfg.slab_in_m)
            across = (q[:, 0] >= u0) & (q[:, 0] < u1)
            face = slab & across & (q[:, 1] >= v0) & (q[:, 1] < v1)
            inner = slab & across & (q[:, 1] >= v0 + s) & (q[:, 1] < v1 - s)
        return face, ~inner

    def face_owned(self, grid: MapGrid) -> B:
        """Gravity cells handed to the face: the plane over the cell's centre lies inside the band
        minus its seams (and across the grid's ``u`` extent)."""
        X, Y = grid.centers()
        q = self.frame.to_face(np.column_stack([X.ravel(), Y.ravel(), self.frame.plane_z(X, Y).ravel()]))
        v0, v1 = self.v_range
        u0, u1 = self.u_range
        s = self.cfg.seam_m
        own = (q[:, 1] >= v0 + s) & (q[:, 1] < v1 - s) & (q[:, 0] >= u0) & (q[:, 0] < u1)
        return np.asarray(own.reshape(grid.shape), bool)

    def surface_z(self, x: F64, y: F64, iterations: int = 4) -> F64:
        """World height of the face map's surface on the vertical line through each ``(x, y)``
        (NaN where the face map has no value, or where its cell is flagged: an overhang holds two
        surfaces and its height may be either, not a place to stand): ``z = plane_z + w(u, v) /
        n_z``, with ``(u, v)`` of the point found by fixed-point iteration (the surface is
        piecewise constant per cell)."""
        x = np.asarray(x, float).ravel()
        y = np.asarray(y, float).ravel()
        z = self.frame.plane_z(x, y)
        nz = float(self.frame.normal[2])
        g = self.map.grid
        w = np.full(x.shape, np.nan)
        held = np.where(self.overhang, np.nan, self.map.z)
        for _ in range(iterations):
            q = self.frame.to_face(np.column_stack([x, y, z]))
            iy, ix, inside = g.cell_index(q[:, 0], q[:, 1])
            w = np.where(inside, held[np.clip(iy, 0, g.ny - 1), np.clip(ix, 0, g.nx - 1)], np.nan)
            z = self.frame.plane_z(x, y) + np.nan_to_num(w) / nz
        return np.where(np.isfinite(w), z, np.nan)

    # -- fusion ---------------------------------------------------------------------------------
    def merge_parts(self, parts: list[ViewPart], p_visible: F64 | B | None = None,
                    eye: F64 | None = None, rays: list[ViewPart] | None = None,
                    window_rad: float | None = None, max_range_m: float | None = None) -> FaceMergeStats:
        """Fuse one view's world points with covariance (the face-routed ones) through §1 in the
        face frame, with the overhang tests of the module docstring; with the camera centre
        ``eye`` (world) the free space along the rays to the view's points (``rays``: all of
        them, default ``parts``) flags the cells it passes under (:meth:`carve`), and the view's
        points on surfaces that face the face flag theirs (``Overhangs.facing_the_face``). With
        ``eye`` and ``window_rad`` (the matching window's angle, ``block_size_px / focal_px``)
        the points whose window spans more than ``resolve_cells`` cells of face
        (:func:`window_span`) are left out of the heights (the incidence limit)."""
        xyz = np.concatenate([p[0] for p in parts]) if parts else np.zeros((0, 3))
        cov = np.concatenate([p[1] for p in parts]) if parts else np.zeros((0, 3, 3))
        commons = [p[2] for p in parts]
        common = None if not parts or any(c is None for c in commons) else np.concatenate(
            [c for c in commons if c is not None])
        q = self.frame.to_face(xyz)
        cov_f = self.frame.cov_to_face(cov)
        beyond = 0
        if rays is not None:
            cut = self.beyond_slab(rays)[self._flat_cells(q)]
            beyond = int(cut.sum())
            xyz, cov, q, cov_f = xyz[~cut], cov[~cut], q[~cut], cov_f[~cut]
            common = None if common is None else common[~cut]
        keep, flagged, n_second = self.overhangs.two_surfaces(self.map, self.cfg.overhang_gap_m, q,
                                                              cov_f[:, 2, 2])
        facing_new = 0
        if eye is not None:
            eye_f = self.frame.to_face(np.reshape(eye, (1, 3)))[0]
            noise = cov_f if common is None else cov_f - self.frame.cov_to_face(common)
            facing, facing_new = self.overhangs.facing_the_face(self.map.grid, self.cfg, eye_f, q, noise)
            n_second += int((keep & facing).sum())
            keep &= ~facing
        grazing = 0
        if eye is not None and window_rad is not None and self.cfg.resolve_cells > 0:
            span = window_span(self.frame, np.reshape(eye, 3), xyz, window_rad)
            wide = keep & ~(span <= self.cfg.resolve_cells * self.cfg.cell_m)
            grazing = int(wide.sum())
            keep &= ~wide
        face_parts: list[tuple[F64, F64, F64 | None]] = [
            (q[keep], cov_f[keep], None if common is None else self.frame.cov_to_face(common[keep]))]
        fe = self.map if isinstance(self.map, FaceElevation) else None
        if fe is not None and eye is not None:
            fe.eye = self.frame.to_face(np.reshape(eye, (1, 3)))[0]
            fe.window_rad = window_rad
            if fe.cfg.hidden_relief:
                ray_xyz = np.concatenate([p[0] for p in (parts if rays is None else rays)]) if parts else xyz
                fe.in_view = in_view(self, np.reshape(eye, 3), ray_xyz, max_range_m)
        try:
            stats = run_merge(self.map, face_parts, p_visible)
        finally:
            if fe is not None:
                fe.eye = None
                fe.in_view = None
                fe.window_rad = None
        air_new = 0
        if eye is not None:
            air_new = self.carve(eye, parts if rays is None else rays)
            facing_new += self.overhangs.beside_flags(self.cfg)
        return FaceMergeStats(stats, flagged + air_new + facing_new, n_second, air_new, facing_new, grazing, beyond)

    def _flat_cells(self, q: F64) -> NDArray[np.intp]:
        """The flat cell of each face point ``q`` (N, 3), ``-1`` off the grid (or not finite)."""
        g = self.map.grid
        with np.errstate(invalid="ignore"):
            iy, ix, inside = g.cell_index(q[:, 0], q[:, 1])
        return np.where(inside & np.isfinite(q[:, 2]), iy * g.nx + ix, -1).astype(np.intp)

    def beyond_slab(self, rays: list[ViewPart]) -> NDArray[np.bool_]:
        """Per flat cell, plus one last entry for points off the grid (always False), whether the
        view (all its points, ``rays``) sees the cell's column mostly outside the slab: more of its
        points over the cell lie behind ``-slab_in_m`` or out beyond ``slab_out_m`` than within
        it, or more of all the views' points so far (this one's included, :attr:`column_in`,
        :attr:`column_out`). Its points inside the slab there are the tail of its noise, or a
        sliver of something else, not the cell's surface: the surface lies where the hand-over
        sends it to the gravity grid (a plane fitted across a face's ledges stands off the true
        face by decimetres near the band's ends), and the face map leaves the cell to other
        views. Pooled, because a view that sees only a sliver of the column (a step's top, the
        rest hidden behind it) puts its few points inside the slab, all of them, where the views
        that see the whole column put most of theirs outside. The counts grow with every call:
        one call per view."""
        g = self.map.grid
        size = g.nx * g.ny
        xyz = np.concatenate([p[0] for p in rays]) if rays else np.zeros((0, 3))
        q = self.frame.to_face(xyz)
        cell = self._flat_cells(q)
        on = cell >= 0
        with np.errstate(invalid="ignore"):
            inside = (q[on, 2] >= -self.cfg.slab_in_m) & (q[on, 2] <= self.cfg.slab_out_m)
        n_in = np.bincount(cell[on][inside], minlength=size)
        n_out = np.bincount(cell[on][~inside], minlength=size)
        self.column_in += n_in
        self.column_out += n_out
        return np.append((n_out > n_in) | (self.column_out > self.column_in), False)

    def carve(self, eye: F64, parts: list[ViewPart]) -> int:
        """The free-space tests of one view (module docstring), after its merge: the rays from the
        camera centre ``eye`` to the points of ``parts`` (world, at most ``air_max_rays`` of them,
        evenly spread), each cut short of its point by ``air_sigma`` times the root of its
        covariance's trace and one cell. A cell is flagged when ``air_min_rays`` rays (of this
        view and earlier ones) passed under its surface by more than the gap plus ``air_sigma``
        sigma (``fsw.core.map.free_space``: :attr:`air`, :attr:`air_w`), or when a view with a
        point in it stood more than ``underside_deg`` under its tangent plane (:attr:`under`).
        Returns the cells newly flagged."""
        cfg = self.cfg
        if cfg.air_max_rays == 0 or not parts:
            return 0
        xyz = np.concatenate([p[0] for p in parts])
        cov = np.concatenate([p[1] for p in parts])
        if len(xyz) == 0:
            return 0
        sel = np.unique(np.linspace(0, len(xyz) - 1, min(len(xyz), cfg.air_max_rays)).astype(np.intp))
        eye_f = self.frame.to_face(np.reshape(eye, (1, 3)))[0]
        return self.overhangs.carve(self.map, cfg, eye_f, self.frame.to_face(xyz[sel]),
                                    self.frame.cov_to_face(cov[sel]))


def window_span(frame: FaceFrame, eye: F64, xyz: F64, window_rad: float) -> F64:
    """The length of face, along the sight line's trace on the face plane, that a stereo matching
    window of angle ``window_rad`` covers at each world point ``(N, 3)`` seen from ``eye``:
    ``window_rad r / cos t`` with ``r`` the range and ``t`` the incidence, the angle between the
    sight line and the face normal (inf for a sight line along the plane)."""
    d = np.asarray(xyz, float) - np.asarray(eye, float).reshape(1, 3)
    r = np.linalg.norm(d, axis=1)
    along_n = np.abs(d @ frame.normal)  # r cos t
    with np.errstate(divide="ignore", invalid="ignore"):
        span = window_rad * r * r / along_n
    return np.asarray(np.where(np.isfinite(span), span, np.inf), float)


def in_view(face: FaceMap, eye: F64, xyz: F64, max_range_m: float | None = None, most: int = 4000) -> B:
    """The face cells (``(ny, nx)``) one view looked at: the centre of the cell on the plane
    lies, seen from the camera centre ``eye`` (world), inside the angular hull of the view's
    points ``xyz`` (world; at most ``most`` of them, evenly spread: its image's extent where it
    matched) and within the camera's usable depth ``max_range_m`` along the view's mean sight
    line (None: the farthest point's range). A cell the view looked at and put no point in was
    hidden from it (or its points were masked); one outside was not seen. The range is the
    camera's, not the farthest point's: past a lip the face the lip hides is hidden, not far."""
    from scipy.spatial import Delaunay, QhullError

    g = face.grid
    p = np.asarray(xyz, float).reshape(-1, 3)
    p = p[np.isfinite(p).all(axis=1)]
    out = np.zeros(g.shape, bool)
    if len(p) < 3:
        return out
    p = p[np.unique(np.linspace(0, len(p) - 1, min(len(p), most)).astype(np.intp))]
    d = p - np.reshape(eye, (1, 3))
    r = np.linalg.norm(d, axis=1)
    axis = d.sum(axis=0)
    axis /= max(float(np.linalg.norm(axis)), 1e-12)
    a = np.cross(axis, [0.0, 0.0, 1.0] if abs(axis[2]) < 0.9 else [1.0, 0.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(axis, a)

    def gnomonic(v: F64) -> tuple[F64, F64]:
        along = v @ axis
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.column_stack([v @ a, v @ b]) / along[:, None], along

    pts, along = gnomonic(d)
    pts = pts[along > 0]
    try:
        hull = Delaunay(pts)
    except (QhullError, ValueError):
        return out
    X, Y = g.centers()
    c = face.frame.to_world(np.column_stack([X.ravel(), Y.ravel(), np.zeros(X.size)])) - np.reshape(eye, (1, 3))
    q, ahead = gnomonic(c)
    inside = np.zeros(len(c), bool)
    ok = (ahead > 0) & ((np.linalg.norm(c, axis=1) <= r.max()) if max_range_m is None else (ahead <= max_range_m))
    inside[ok] = hull.find_simplex(q[ok]) >= 0
    return np.asarray(inside.reshape(g.shape), bool)


def run_merge(emap: ElevationMap, parts: list[tuple[F64, F64, F64 | None]],
              p_visible: F64 | B | None) -> MergeStats:
    """``emap.merge_parts_steps`` run to its end (``parts`` is consumed)."""
    return run_to_end(emap.merge_parts_steps(list(parts), p_visible=p_visible))


def split_parts(parts: list[ViewPart], face: FaceMap) -> tuple[list[ViewPart], list[ViewPart]]:
    """A view's parts split by the hand-over (:meth:`FaceMap.routes`): ``(face, gravity)``."""
    to_f: list[ViewPart] = []
    to_g: list[ViewPart] = []
    for xyz, cov, common in parts:
        f, g = face.routes(xyz)
        for sel, out in ((f, to_f), (g, to_g)):
            if sel.any():
                out.append((xyz[sel], cov[sel], None if common is None else common[sel]))
    return to_f, to_g


def hand_over_z(gravity: ElevationMap, face: FaceMap) -> F64:
    """The gravity grid's heights with the face-owned cells answered by the face map (NaN
    where the owner has no value): one heightfield for planners and queries across the seam."""
    own = face.face_owned(gravity.grid)
    out = gravity.z.copy()
    X, Y = gravity.grid.centers()
    out[own] = face.surface_z(X[own], Y[own])
    return out


def fit_face_map(gravity: ElevationMap, fusion: FusionConfig | None = None,
                 cfg: FaceMapConfig | None = None) -> FaceMap:
    """An empty face map on the face of ``gravity``: the plane fitted to its steep cells
    (:func:`~fsw.core.map.face_plane.fit_face_plane`), its band
    (:func:`~fsw.core.map.face_plane.face_band`), cells as many over the face as the gravity
    grid's over its footprint (:func:`~fsw.core.map.face_plane.equal_memory_cell`; ``cfg``'s
    other settings as given). Raises ``ValueError`` where ``gravity`` holds no face yet."""
    base = cfg or FaceMapConfig()
    frame = fit_face_plane(gravity, base.min_slope_deg)
    u, v = face_band(gravity, frame, base.min_slope_deg)
    fc = replace(base, cell_m=equal_memory_cell(gravity.grid.cell, frame.slope_deg))
    return FaceMap(frame, (float(u[0]), float(u[1])), (float(v[0]), float(v[1])), fc, fusion)
