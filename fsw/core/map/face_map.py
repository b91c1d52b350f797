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

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from fsw.core.geometry import MapGrid
from fsw.core.map.elevation_map import ElevationMap, FusionConfig, MergeStats, nan_gradient
from fsw.core.map.face_plane import FaceFrame, steep_points
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


def face_band(gravity: ElevationMap, frame: FaceFrame, min_slope_deg: float = 45.0,
              inlier_m: float = 0.15, margin_m: float = 0.3) -> tuple[F64, F64]:
    """``((u_min, u_max), (v_min, v_max))`` of the face map. Along the strike, the gravity grid's
    whole extent (its corners on the plane). Along the dip, from ``margin_m`` (vertical) above
    the floor to ``margin_m`` below the plateau, where the plane meets their heights (the
    medians of the mapped gentle cells out in front of the plane and below its centre, and of
    those behind it and above); the transitions stay in the gravity grid, where the ground
    turns away from the plane. Without a floor or a plateau mapped, that end is the 1st (99th)
    percentile of the steep cells within ``inlier_m`` of the plane."""
    q = frame.to_face(steep_points(gravity, min_slope_deg)[0])
    q = q[np.abs(q[:, 2]) <= inlier_m]
    if len(q) == 0:
        raise ValueError("no steep mapped cells on the plane")
    x0, x1, y0, y1 = gravity.grid.extent
    cx, cy = np.array([x0, x1, x1, x0]), np.array([y0, y0, y1, y1])
    corners = frame.to_face(np.column_stack([cx, cy, frame.plane_z(cx, cy)]))
    u = np.array([corners[:, 0].min(), corners[:, 0].max()])
    v = np.percentile(q[:, 1], [1.0, 99.0])
    g = gravity.grid
    gy, gx = np.gradient(gravity.z, g.cell)
    with np.errstate(invalid="ignore"):
        gentle = gravity.mapped & (np.hypot(gx, gy) < np.tan(np.radians(min_slope_deg)))
    X, Y = g.centers()
    z = gravity.z[gentle]
    qg = frame.to_face(np.column_stack([X[gentle], Y[gentle], z]))
    ev_z = float(frame.R[2, 1])
    floor = (qg[:, 2] > 0) & (qg[:, 1] < 0)
    top = (qg[:, 2] < 0) & (qg[:, 1] > 0)
    if floor.sum() >= 10:
        v[0] = max(v[0], (float(np.median(z[floor])) + margin_m - frame.origin[2]) / ev_z)
    if top.sum() >= 10:
        v[1] = min(v[1], (float(np.median(z[top])) - margin_m - frame.origin[2]) / ev_z)
    if v[1] <= v[0]:
        raise ValueError("the face band is empty")
    return u, np.asarray(v, float)


class FaceElevation(ElevationMap):
    """The face map's grid: §1.1 with five changes (docs/algorithm.md §8.1).

    *The relief the view cannot resolve.* A view's gradient ``g`` (of its own cell means, the
    slope term of §1.2) is the face's relief blurred by the points' error along the face: at
    grazing incidence it is about half the local slope. The slope term takes the slope as
    uncertain, ``g + dg`` with ``dg`` zero-mean and, per axis, the variance of the resolved
    gradient (``E[g_i^2] = 2 g_i^2``): each point's variance gains
    ``g_u^2 P_uu + g_v^2 P_vv`` (:meth:`_vertical_variance`). And a view's points sample a cell
    where that view sees it (at grazing incidence, the parts facing the camera), not at its
    centre, once per view: the view's cell measurement gains ``E|g|^2 c^2 / 12 =
    2 |g|^2 c^2 / 12`` (the variance of a plane of that slope over a cell of side ``c``),
    independent between views (:meth:`_fuse`).

    *The steps beside a cell.* At grazing incidence a view's matching windows and its sight
    lines mix a cell with the relief beside it: next to a step out of the face the view sees the
    step's side and its top, not the cell's own ground behind it, and a cell on a step's top
    gets the lower ground beyond its edge. The view's cell measurement gains
    ``(r_up^2 + r_down^2) / 3``, with ``r_up`` (``r_down``) how far the view's own cell means
    within ``step_cells`` cells rise above (fall below) the cell's tangent plane (its min-mod
    gradient: a plane gives none): the sample lies anywhere between the cell's ground and the
    step's, the second moment of a uniform error over the step (:func:`relief_variance`). It is
    a grazing view's: each step counts by the share of the cell it reaches (:func:`step_variance`),
    ``h tan t`` over one cell, at most 1, with ``h`` the step and ``t`` the incidence of the view's
    sight line to the cell (the face a step hides or mixes in; a view head-on mixes none), and a
    step that does not rise between the camera and the cell (no shadow on it) only as far as
    two of the view's matching windows reach (``window_rad``).

    *The steps a view did not see* (``[fusion] hidden_relief``). Beside a cell the view did not
    measure (the relief hid it) the steps' term finds no step; the cell gains the variance of a
    step as large as the steps the view saw elsewhere, or, in a view that resolved no relief of
    its own, as the cell's height out of the plane (:func:`hidden_relief`).

    *The weights.* Of a cell's height and a view's, each is weighted by its whole variance, not
    by its independent part alone as in §1.1: the common part (the camera pose's, a share of the
    view's) is one error within one agent's frame, but two agents' poses err apart, and the face
    map is where their views meet. The variance is §1.1's (its common part does not average down).

    *The gate.* A measurement the gate refuses (farther than ``gate_sigma`` from the cell)
    replaces the cell when its variance is smaller than the cell's: of two inconsistent surfaces
    (two agents' views of one cell, one of them wrong) the cell holds the better-supported one,
    whichever came first, so fusing a second agent never leaves a cell worse than the better
    agent's own."""

    def __init__(self, grid: MapGrid, cfg: FusionConfig | None = None, step_cells: int = 2) -> None:
        super().__init__(grid, cfg)
        self.step_cells = step_cells
        # the camera centre (face frame) of the view being merged, or None (unknown: the steps'
        # term in full); FaceMap.merge_parts sets it for one merge
        self.eye: F64 | None = None
        # the cells the view being merged looked at (:func:`in_view`), or None (all of them);
        # FaceMap.merge_parts sets it for one merge
        self.in_view: B | None = None
        # the stereo matching window's angle of the view being merged (rad), or None (unknown:
        # no bound on how far a step mixes in); FaceMap.merge_parts sets it for one merge
        self.window_rad: float | None = None

    def _vertical_variance(self, grad: tuple[F64, F64], c6: tuple[F64, ...], footprint: bool) -> F64:
        """§1.2's slope term plus the unresolved slope's share, ``g_u^2 P_uu + g_v^2 P_vv``, in a
        point's whole variance (``footprint``; the view's common part is left as it is)."""
        out = super()._vertical_variance(grad, c6, footprint)
        if footprint and self.cfg.slope_term:
            gx, gy = grad
            out = out + gx * gx * c6[0] + gy * gy * c6[3]
        return np.asarray(out)

    def _fuse(self, cells: NDArray[np.intp], zm: F64, vm: F64, vm_pose: F64 | None = None) -> tuple[int, int, int]:
        if self.cfg.slope_term and cells.size:
            vm = vm + relief_variance(self.grid, cells, zm, self.step_cells, self.eye, self.cfg.hidden_relief,
                                      self.in_view, self.window_rad)
        z, var, n = self.z.reshape(-1), self.var.reshape(-1), self.n.reshape(-1)
        z0, v0, n0 = z[cells], var[cells], n[cells]
        with np.errstate(invalid="ignore"):
            near = np.abs(zm - z0) <= self.cfg.gate_sigma * np.sqrt(v0 + vm)
        swap = (n0 > 0) & ~near & (vm < v0)
        inlier = (n0 > 0) & near
        out = super()._fuse(cells, zm, vm, vm_pose)
        c = cells[inlier]  # the heights by the whole variances (the agents' common parts are not one error)
        z[c] = (vm[inlier] * z0[inlier] + v0[inlier] * zm[inlier]) / (v0[inlier] + vm[inlier])
        c = cells[swap]
        z[c], var[c] = zm[swap], vm[swap]
        vp = np.zeros(int(swap.sum())) if vm_pose is None else np.clip(vm_pose[swap], 0.0, vm[swap])
        self.var_common.reshape(-1)[c] = self.cfg.view_correlation * (vm[swap] - vp) + vp
        return out


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


def relief_variance(grid: MapGrid, cells: NDArray[np.intp], zm: F64, step_cells: int = 0,
                    eye: F64 | None = None, hidden: bool = False, looked: B | None = None,
                    window_rad: float | None = None) -> F64:
    """Per measured cell (flat ``cells``, the view's cell means ``zm``), the variance of a view's
    sample of the cell against its centre: ``E|g|^2 c^2 / 12`` with ``E|g|^2 = 2 |g|^2`` (``g``
    the gradient of the view's cell means, its unresolved part as wide again), plus, with
    ``step_cells > 0``, ``(r_up^2 + r_down^2) / 3`` for the steps beside the cell: ``r_up``
    (``r_down``) how far the view's cell means within ``step_cells`` cells rise above (fall
    below) the cell's tangent plane, each step scaled by the share of the cell it reaches seen
    from ``eye`` (face frame; None: in full, :func:`step_variance`): ``h tan t`` (the length of
    face a step ``h`` high hides or mixes in at the incidence ``t`` of the sight line to the
    cell) over one cell, at most 1; a step that does not rise between the camera and the cell
    casts no shadow on it and reaches it only through the stereo matching windows (of angle
    ``window_rad``; None: unknown, no such bound), within two window spans of the step.
    With ``hidden`` (and ``step_cells > 0``), a cell next to a cell the view did not measure
    though it looked at it (of its eight neighbours inside the grid and in ``looked``,
    :func:`in_view`; None: all of them) also gains ``h^2 / 3``, scaled by ``h tan t`` over one
    cell, at most 1, for the step the view could not see beside it: as large as the steps it saw
    (``h^2 = 3 rho^2``, ``rho^2`` the view's mean steps' variance over the cells whose whole
    reach it measured, :func:`hidden_relief`), or, when it measured no such cell and so shows no
    relief of its own, as the cell's own height out of the fitted plane (``h = zm``: the face
    beside a rock's top the view saw alone lies on the plane)."""
    dense = np.full(grid.nx * grid.ny, np.nan)
    dense[cells] = zm
    z = dense.reshape(grid.shape)
    gy, gx = nan_gradient(z, grid.cell)
    g2 = (gx * gx + gy * gy).reshape(-1)[cells]
    out = 2.0 * g2 * grid.cell**2 / 12.0
    if step_cells > 0:
        sight = None if eye is None else _sight_lines(grid, z, eye, window_rad)
        out = out + step_variance(z, step_cells, grid.cell, sight).reshape(-1)[cells]
        if hidden:
            tan_t = None if sight is None else sight[2].reshape(-1)[cells]
            beside, rho2 = hidden_relief(z, step_cells, looked)
            h2 = np.full(len(cells), 3.0 * rho2) if rho2 is not None else zm * zm
            out = out + beside.reshape(-1)[cells] * _step_share(np.sqrt(h2), tan_t, grid.cell) * h2 / 3.0
    return np.asarray(out, float)


Sight = tuple[F64, F64, F64, F64]  # per cell: the unit direction to the camera in (u, v), tan t, window span


def _sight_lines(grid: MapGrid, z: F64, eye: F64, window_rad: float | None) -> Sight:
    """Per cell of a view's heightfield ``z`` (face frame, NaN unknown: taken on the plane), seen
    from the camera centre ``eye``: the unit direction ``(du, dv)`` from the cell towards the
    camera along the face, ``tan t`` (``t`` the incidence of the sight line on the face) and the
    length of face one matching window of angle ``window_rad`` covers there along the sight
    line's trace, ``window_rad r / cos t`` (:func:`window_span`; inf when ``window_rad`` is
    None)."""
    X, Y = grid.centers()
    e = np.reshape(eye, 3)
    d = np.stack([X - e[0], Y - e[1], np.nan_to_num(z) - e[2]])
    across = np.hypot(d[0], d[1])
    along_n = np.abs(d[2])
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        du, dv = np.nan_to_num(-d[0] / across), np.nan_to_num(-d[1] / across)
        tan_t = across / along_n
        span = (np.full(z.shape, np.inf) if window_rad is None
                else window_rad * (across * across + along_n * along_n) / along_n)
    return (np.asarray(du, float), np.asarray(dv, float), np.asarray(tan_t, float),
            np.asarray(np.nan_to_num(span, nan=np.inf), float))


def _step_share(h: F64, tan_t: F64 | None, cell_m: float) -> F64:
    """The share of a step ``h`` high a view mixes into a cell at the incidence ``t`` of its
    sight line: ``h tan t`` over one cell, at most 1 (None: the incidence is unknown, 1)."""
    if tan_t is None:
        return np.ones(len(h))
    with np.errstate(invalid="ignore"):
        share = np.nan_to_num(h * tan_t / cell_m, nan=1.0, posinf=1.0)
    return np.asarray(np.clip(share, 0.0, 1.0), float)


def hidden_relief(z: F64, reach: int, looked: B | None = None) -> tuple[B, float | None]:
    """``(beside, rho^2)`` for one view's heightfield of cell means ``z`` (NaN: the view put no
    point there): the cells it measured with a neighbour it did not though it looked at it (of
    their eight inside the grid, beyond which the ground is the gravity grid's, and in
    ``looked``, None: all; a cell outside the view's image or range was not hidden), and the view's mean steps'
    variance ``(r_up^2 + r_down^2) / 3`` (:func:`step_heights` within ``reach``) over the cells
    whose whole reach it measured (None when it measured no such cell).

    At grazing incidence a view misses the ground the relief hides from it (behind a rise, in
    front of a step turned away) and puts a cell's points on what it sees of the cell: the top of
    the rise. Beside a neighbour it did not see, its own cell means show no step and the steps'
    term adds nothing, yet the cell's ground may lie as far below its sample as the relief
    reaches; the relief the view could not see is taken as large as the relief it saw."""
    known = np.isfinite(z)
    if not known.any():
        return np.zeros(z.shape, bool), None
    missed = ~known if looked is None else ~known & looked
    ring = ndimage.convolve(missed.astype(np.float64), np.ones((3, 3)), mode="constant", cval=0.0)
    beside = known & (ring > 0.5)
    size = 2 * reach + 1
    full = known & (ndimage.convolve(known.astype(np.float64), np.ones((size, size)), mode="constant",
                                     cval=1.0) > size * size - 0.5)
    up, down = step_heights(z, reach)
    steps = (up * up + down * down) / 3.0
    rho2 = float(np.mean(steps[full])) if full.any() else None
    return np.asarray(beside, bool), rho2


def _deviations(z: F64, reach: int) -> Iterator[tuple[int, int, F64]]:
    """``(dy, dx, d)`` for every offset within ``reach`` cells (the square around each cell, the
    cell itself included): how far the known cell there lies above the cell's tangent plane (NaN
    where either is unknown). The plane's gradient is, per axis, the min-mod of the two one-sided
    differences to the next cells (the smaller, 0 where they differ in sign; the one known where
    the other is not): a plane gives 0, a step beside the cell its height."""
    ny, nx = z.shape
    p = np.pad(z, reach, constant_values=np.nan)

    def at(dy: int, dx: int) -> F64:
        return np.asarray(p[reach + dy: reach + dy + ny, reach + dx: reach + dx + nx], float)

    def slope(a: F64, b: F64) -> F64:
        with np.errstate(invalid="ignore"):
            m = np.where(a * b > 0, np.sign(a) * np.minimum(np.abs(a), np.abs(b)), 0.0)
            m = np.where(np.isnan(a), b, np.where(np.isnan(b), a, m))
        return np.asarray(np.nan_to_num(m), float)

    gx = slope(at(0, 1) - z, z - at(0, -1))
    gy = slope(at(1, 0) - z, z - at(-1, 0))
    for dy in range(-reach, reach + 1):
        for dx in range(-reach, reach + 1):
            yield dy, dx, at(dy, dx) - z - gx * dx - gy * dy


def step_heights(z: F64, reach: int) -> tuple[F64, F64]:
    """Per cell of a heightfield ``z`` (NaN unknown), how far the known cells within ``reach``
    cells (the square around it) rise above and fall below the cell's tangent plane (``(up,
    down)``, both >= 0; 0 for unknown cells; the plane of :func:`_deviations`)."""
    up, down = np.zeros(z.shape), np.zeros(z.shape)
    for _, _, d in _deviations(z, reach):
        up = np.fmax(up, d)
        down = np.fmax(down, -d)
    return np.asarray(np.nan_to_num(up), float), np.asarray(np.nan_to_num(down), float)


def step_variance(z: F64, reach: int, cell_m: float, sight: Sight | None = None) -> F64:
    """Per cell of a view's heightfield ``z`` (NaN unknown), the steps' variance ``(r_up^2 +
    r_down^2) / 3`` (docs/algorithm.md §8.1): ``r_up^2`` (``r_down^2``) the largest ``s d^2``
    over the cells within ``reach`` that rise above (fall below) the cell's tangent plane by
    ``d`` (:func:`_deviations`), ``s`` the share of the cell that step reaches, seen along
    ``sight`` (:func:`_sight_lines`; None: 1). A step ``h = |d|`` high hides or mixes in ``h tan
    t`` of face at the incidence ``t``; a rise between the camera and the cell (its offset
    towards the camera along the face, less than a cell across the sight line's trace) shadows
    the cell by that much, ``s = h tan t / c``; any other step (a rise beyond the cell, turned to
    the camera; a fall; a rise off to the side) casts no shadow on the cell and reaches it only
    through the stereo matching windows that straddle it and the depth they mix, taken as two
    window spans ``w`` (:func:`window_span`; a bound set on the face-map experiment's tuning
    scenes): ``s = min(h tan t, 2 w - gap) / c`` with ``gap`` the face between the two cells;
    both at most 1. A view far off at grazing incidence (the RECON-bot's, windows several cells
    long on the face) keeps every step within reach; a view close to the face (the Cliff-bot's)
    keeps the steps that shadow the cell and the ones next to it."""
    up, down = np.zeros(z.shape), np.zeros(z.shape)
    for dy, dx, d in _deviations(z, reach):
        if sight is None:
            share: F64 | float = 1.0
        else:
            du, dv, tan_t, span = sight
            with np.errstate(invalid="ignore", over="ignore"):
                mixed = np.abs(d) * tan_t
                across = np.abs(dx * dv - dy * du)  # the step's offset across the sight line, in cells
                shadow = (d > 0) & (dx * du + dy * dv > 0) & (across < 1.0)
                gap = cell_m * (max(abs(dx), abs(dy)) - 1)
                reach_m = np.where(shadow, mixed, np.minimum(mixed, 2.0 * span - gap))
            share = np.clip(np.nan_to_num(reach_m / cell_m, nan=1.0, posinf=1.0), 0.0, 1.0)
        with np.errstate(invalid="ignore"):
            up = np.fmax(up, np.where(d > 0, share * d * d, 0.0))
            down = np.fmax(down, np.where(d < 0, share * d * d, 0.0))
    return np.asarray((np.nan_to_num(up) + np.nan_to_num(down)) / 3.0, float)


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
