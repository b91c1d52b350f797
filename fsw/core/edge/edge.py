"""The cliff edge from the elevation map (docs/algorithm.md §2).

1. Edge points. The *safe region* is the mapped plateau: cells within ``plateau_tol_m`` of
   the rover's ground (a plane fitted around the rover, bent to follow rolling ground,
   ``fsw.core.edge.ground_plane``: level ground stays level, a sloped or rolling plateau is
   followed), in the connected piece nearest the rover. A safe
   cell is an edge cell when, looking outward across its boundary in one of the eight grid
   directions, the first mapped cell within ``search_m`` lies more than ``step_m`` lower
   (than the ground plane there; cells in between may be unknown: the ground right under a
   drop is occluded from the plateau), in at least ``min_drop_dirs`` of the eight directions: a drop is an extended
   feature, while a frontier cell beside a large unknown area (the blind zone around the
   rover) may glimpse a drop far away along a single diagonal. The edge point is placed on
   the cell's outer side, half a cell out. The plain frontier of the map (safe cells next to
   unknown cells with no drop behind them) and holes inside the plateau are not edges.
2. Fits. Method 4/5: the best-fit non-convex polygon of the safe region (OpenCV contours,
   then Douglas-Peucker simplification by ``simplify_m``); the edge is the part of its
   boundary that runs along the edge points. Method 3: one straight segment, the total least
   squares line through the edge points, spanning them.
3. Every fit gives the edge as lines oriented with the safe side on the LEFT, a signed
   distance to it (positive on the safe side; used by the geofence) and a path along the
   edge set back into the safe side (the candidate rover positions of §3).
"""

from __future__ import annotations

from collections.abc import Callable, Generator
from dataclasses import dataclass

import cv2
import numpy as np
import shapely
from numpy.typing import NDArray
from scipy import ndimage
from shapely.geometry import LineString, MultiLineString, MultiPolygon, Polygon
from shapely.geometry.base import BaseGeometry

from fsw.core.edge.edge_offset import END_TANGENT_M, edge_path, end_normal, trim_hooks
from fsw.core.edge.edge_ring import bridge_runs, densify_ring
from fsw.core.edge.ground_plane import ground_surface
from fsw.core.map.elevation_map import ElevationMap
from fsw.core.steps import run_to_end
from fsw.framework.params import param

F64 = NDArray[np.float64]
BRIDGE_M = 0.25  # edge runs this close along the polygon boundary are one run (fit_polygon)
CLIP_INSIDE_M = 0.05  # a barrier extension stops where it gets this deep into the safe polygon
__all__ = ["EdgeConfig", "EdgeModel", "edge_cells", "edge_path", "fit_line", "fit_polygon", "fit_polygon_steps"]
_DIRS = ((0, 1), (1, 1), (1, 0), (1, -1), (0, -1), (-1, -1), (-1, 0), (-1, 1))  # (dy, dx)


@dataclass(frozen=True)
class EdgeConfig:
    """Edge extraction and fitting (config ``[edge]``)."""

    step_m: float = param(0.10, lo=0.005, hi=10.0, units="m", doc="drop that makes an edge")
    plateau_tol_m: float = param(
        0.03, lo=0.001, hi=5.0, units="m", doc="a safe cell is within this of the ground height"
    )
    max_slope_deg: float = param(
        15.0, lo=0.0, hi=45.0, units="deg", doc="steepest plateau the ground plane may take"
    )
    surface_scale_m: float = param(
        0.15, lo=0.0, hi=5.0, units="m", doc="the ground surface follows rolling ground at this scale (0: a plane)"
    )
    search_m: float = param(
        1.5, lo=0.0, hi=10.0, units="m", doc="how far past the plateau to look for the drop"
    )
    min_drop_dirs: int = param(
        2, lo=1, hi=8, doc="grid directions in which a boundary cell must see the drop (1: any)"
    )
    min_region_cells: int = param(30, lo=1, hi=10**7, doc="smallest safe-region piece kept")
    join_m: float = param(
        0.6, lo=0.0, hi=5.0, units="m", doc="plateau pieces closer than this are one piece"
    )
    simplify_m: float = param(0.03, lo=0.0, hi=1.0, units="m", doc="polygon simplification")
    match_m: float = param(
        0.06, lo=0.0, hi=1.0, units="m", doc="polygon vertices this close to edge points are edge"
    )
    min_edge_len_m: float = param(0.3, lo=0.0, hi=100.0, units="m", doc="shorter runs dropped")
    setback_m: float = param(
        0.75, lo=0.0, hi=10.0, units="m", doc="path offset from the edge (body centre)"
    )
    path_spacing_m: float = param(0.25, lo=0.01, hi=10.0, units="m")


@dataclass(frozen=True)
class EdgeCells:
    """Edge points (M, 2) world x, y, the safe-region mask they bound, and the drop: mapped
    cells more than ``step_m`` below the rover's ground (what the geofence keeps wheels
    away from while no edge is fitted, ``fsw.core.edge.geofence``)."""

    points_xy: F64
    safe: NDArray[np.bool_]
    drop: NDArray[np.bool_] | None = None


@dataclass(frozen=True)
class EdgeSegments:
    """An edge's barrier (``EdgeModel.barrier``) as segments ``a[k] -> b[k]``, with the side
    normals at their starts and ends (``na``, ``nb``) and which of them start or end a line
    (``ends``, (K, 2))."""

    a: F64
    b: F64
    na: F64
    nb: F64
    ends: NDArray[np.bool_]
    open_ends: bool  # as the model's: ground past a line's end is not beyond the edge

    def signed_distance(self, xy: F64) -> F64:
        """Distance of points to the segments, positive on the safe side (§2).

        The side is that of the nearest point of the edge: the segment's left normal, or at
        a vertex the mean of its two segments' normals, so bays and capes of a non-convex
        edge are classified correctly (a one-sided buffer would spill across a narrow bay).
        At a line's end the normal is that of its overall end direction (over
        ``END_TANGENT_M``, as the extension's): a short hook at the end of a fit must not turn
        the ground beyond the end to the other side.
        """
        pts = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        a, na, nb = self.a, self.na, self.nb
        ab = self.b - a
        L2 = np.maximum((ab**2).sum(1), 1e-18)
        ap = pts[:, None, :] - a[None]
        t = np.clip((ap * ab[None]).sum(2) / L2[None], 0.0, 1.0)  # (M, K)
        near = a[None] + t[..., None] * ab[None]
        d2 = ((pts[:, None, :] - near) ** 2).sum(2)
        j = np.argmin(d2, axis=1)
        m = np.arange(pts.shape[0])
        tj = t[m, j]
        seg_n = np.column_stack([-ab[j, 1], ab[j, 0]])
        n = np.where((tj <= 0.0)[:, None], na[j], np.where((tj >= 1.0)[:, None], nb[j], seg_n))
        side = np.sign(((pts - near[m, j]) * n).sum(1))
        side[side == 0] = 1.0
        if self.open_ends:  # past a line's end the fit says nothing: not beyond the edge
            side[((tj <= 0.0) & self.ends[j, 0]) | ((tj >= 1.0) & self.ends[j, 1])] = 1.0
        return np.asarray(side * np.sqrt(d2[m, j]))


@dataclass(frozen=True)
class EdgeModel:
    """A fitted edge. ``lines`` run with the safe side on their left."""

    method: str  # "polygon" (Methods 4/5) or "line" (Method 3)
    points_xy: F64
    lines: MultiLineString
    safe_polygon: Polygon | MultiPolygon | None  # the mapped plateau: every piece of it
    stand: BaseGeometry | None = None  # ground the rover stands on: no extension crosses it
    stop_at: Callable[[F64], NDArray[np.bool_]] | None = None  # (N, 2) -> True: extension ends
    open_ends: bool = False  # signed_distance: ground past a line's end is not beyond the edge

    @property
    def empty(self) -> bool:
        return self.lines.is_empty

    def barrier(self, extend_m: float) -> MultiLineString:
        """The edge lines, each extended straight by ``extend_m`` past both ends (the edge is
        taken to go on beyond where the map saw it). An extension stops where it enters the
        mapped plateau (``safe_polygon`` shrunk by ``CLIP_INSIDE_M``): the map saw level ground
        there, so the edge does not go on across it (a hooked end would otherwise swing its
        continuation over the plateau, behind the rover). Nor does it cross ``stand``, the
        ground under the rover (``Geofence.set_edge``): the rover stands on safe ground; and
        it ends where ``stop_at`` says (the geofence: unknown ground, which it never lets a
        wheel onto anyway)."""
        inner = None
        if self.safe_polygon is not None and extend_m > 0:
            inner = self.safe_polygon.buffer(-CLIP_INSIDE_M)
            inner = None if inner.is_empty else inner
        if self.stand is not None and extend_m > 0:
            inner = self.stand if inner is None else inner.union(self.stand)
        out = []
        for ln in self.lines.geoms:
            c = trim_hooks(np.asarray(ln.coords)) if self.open_ends else np.asarray(ln.coords)
            ln = LineString(c)
            if extend_m > 0 and len(c) >= 2:
                # Extend along the end's overall direction (over END_TANGENT_M), not the last
                # segment's: a short hook at the end of a fit must not swing the extension.
                span = min(END_TANGENT_M, ln.length / 2.0)
                p0 = np.asarray(ln.interpolate(span).coords[0])
                p1 = np.asarray(ln.interpolate(ln.length - span).coords[0])
                e0 = _extension(c[0], c[0] - p0, extend_m, inner, self.stop_at)
                e1 = _extension(c[-1], c[-1] - p1, extend_m, inner, self.stop_at)
                c = np.vstack([e0[None] if e0 is not None else np.zeros((0, 2)), c,
                               e1[None] if e1 is not None else np.zeros((0, 2))])
            out.append(LineString(c))
        return MultiLineString(out)

    def signed_distance(self, xy: F64, extend_m: float = 0.0) -> F64:
        """Distance of points to the (extended) edge, positive on the safe side (§2):
        :meth:`EdgeSegments.signed_distance` on this edge's :meth:`segments`."""
        pts = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        if self.empty:
            return np.full(pts.shape[0], np.inf)
        return self.segments(extend_m).signed_distance(pts)

    def segments(self, extend_m: float) -> EdgeSegments:
        """The segments of :meth:`barrier` with their side normals, for
        :meth:`EdgeSegments.signed_distance` (a caller that tests many points against one
        barrier keeps them instead of extending the edge again at each call). Not for an
        empty edge."""
        a_l, b_l, na_l, nb_l, end_l = [], [], [], [], []
        for ln in self.barrier(extend_m).geoms:
            c = np.asarray(ln.coords)
            seg = c[1:] - c[:-1]
            nrm = np.column_stack([-seg[:, 1], seg[:, 0]])
            nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-12)
            vn = np.vstack([end_normal(ln, True), nrm[:-1] + nrm[1:], end_normal(ln, False)])
            a_l.append(c[:-1])
            b_l.append(c[1:])
            na_l.append(vn[:-1])
            nb_l.append(vn[1:])
            ends = np.zeros((len(seg), 2), bool)  # segment starts / ends the line
            ends[0, 0] = ends[-1, 1] = True
            end_l.append(ends)
        return EdgeSegments(np.concatenate(a_l), np.concatenate(b_l), np.concatenate(na_l), np.concatenate(nb_l),
                            np.concatenate(end_l), self.open_ends)

    def mean_distance_to(self, truth_xy: F64, step_m: float) -> float:
        """Mean distance from points sampled every ``step_m`` along the fit to a polyline."""
        if self.empty:
            return float("nan")
        pts = sample_lines(self.lines, step_m)
        truth = LineString(np.asarray(truth_xy, dtype=np.float64))
        return float(np.mean(shapely.distance(shapely.points(pts), truth)))


def _extension(end: F64, t: F64, extend_m: float, inner: BaseGeometry | None,
               stop_at: Callable[[F64], NDArray[np.bool_]] | None = None) -> F64 | None:
    """The far point of the straight extension from ``end`` along ``t``: ``extend_m`` out, or
    where it first enters ``inner`` or ``stop_at`` holds (None: it would start there)."""
    t, length = t / max(float(np.hypot(*t)), 1e-12), extend_m
    if inner is not None or stop_at is not None:
        s = np.linspace(0.0, extend_m, max(2, int(np.ceil(extend_m / 0.01)) + 1))
        q = end[None] + s[:, None] * t[None]
        stop = np.zeros(len(q), bool) if inner is None else shapely.contains_xy(inner, q[:, 0], q[:, 1])
        if stop_at is not None:
            stop[1:] |= stop_at(q[1:])
        hit = np.flatnonzero(stop)
        if hit.size:
            length = float(s[hit[0] - 1]) if hit[0] > 0 else 0.0
    return end + length * t if length > 1e-9 else None


def safe_region(emap: ElevationMap, ground_z_m: float, seed_xy: tuple[float, float],
                cfg: EdgeConfig, ref: F64 | None = None) -> NDArray[np.bool_]:
    """The mapped plateau the rover stands on: cells within ``plateau_tol_m`` of its ground
    (``ref``, else :func:`ground_surface`: the ground around it, level, sloped or rolling), in the
    connected piece nearest ``seed_xy`` (pieces closer than ``join_m`` count as one).
    Level ground that is not connected to the rover (the top of a box in the pit, a
    floor beyond the far side of the pit) is not safe ground."""
    z = emap.z
    ref = ground_surface(emap, ground_z_m, seed_xy, cfg) if ref is None else ref
    level = emap.mapped & np.isfinite(z) & (np.abs(z - ref) <= cfg.plateau_tol_m)
    if not level.any():
        return level
    # grow every piece by join_m / 2: pieces closer than join_m touch and share a label
    grown = ndimage.distance_transform_edt(~level) <= cfg.join_m / (2.0 * emap.grid.cell)
    lab, _ = ndimage.label(grown | level, structure=np.ones((3, 3)))
    lab = np.where(level, lab, 0)
    sizes = np.bincount(lab.ravel())
    big = sizes[lab] >= cfg.min_region_cells
    big &= lab > 0
    if not big.any():
        return big
    g = emap.grid
    iy, ix = np.nonzero(big)
    d2 = (g.x0 + (ix + 0.5) * g.cell - seed_xy[0]) ** 2 + (g.y0 + (iy + 0.5) * g.cell
                                                          - seed_xy[1]) ** 2
    nearest = lab[iy[np.argmin(d2)], ix[np.argmin(d2)]]
    return np.asarray(lab == nearest)


def edge_cells(emap: ElevationMap, ground_z_m: float, seed_xy: tuple[float, float],
               cfg: EdgeConfig) -> EdgeCells:
    """Edge points of the map: safe cells whose outward neighbour run ends in a drop (§2).

    ``ground_z_m`` is the height of the ground the rover stands on and ``seed_xy`` a point
    of it (the rover's position)."""
    return run_to_end(edge_cells_steps(emap, ground_z_m, seed_xy, cfg))


def edge_cells_steps(emap: ElevationMap, ground_z_m: float, seed_xy: tuple[float, float],
                     cfg: EdgeConfig) -> Generator[None, None, EdgeCells]:
    """:func:`edge_cells` for a slack job: yields after the safe region and after each half
    of the outward directions."""
    z = emap.z
    mapped = emap.mapped & np.isfinite(z)
    ref = ground_surface(emap, ground_z_m, seed_xy, cfg)
    yield None
    safe = safe_region(emap, ground_z_m, seed_xy, cfg, ref)
    yield None
    # per cell: 0 unknown, 1 lower by more than a step, 2 anything else known (or off-grid)
    code = np.where(mapped, np.where(z < ref - cfg.step_m, 1, 2), 0).astype(np.int8)
    code = np.pad(code, 1, constant_values=2)
    # only safe cells on the boundary of the safe region can be edge cells
    inner = ndimage.binary_erosion(safe, np.ones((3, 3)), border_value=0)
    cy, cx = np.nonzero(safe & ~inner)
    k_max = max(1, int(round(cfg.search_m / emap.grid.cell)))
    hit = np.zeros((cy.size, 2))
    dirs = np.zeros(cy.size, np.int32)
    ny, nx = z.shape
    for i, (dy, dx) in enumerate(_DIRS):
        if i and i % 4 == 0:
            yield None
        norm = float(np.hypot(dy, dx))
        open_ = np.ones(cy.size, bool)
        found = np.zeros(cy.size, bool)
        for k in range(1, max(1, int(round(k_max / norm))) + 1):
            yy = np.clip(cy + k * dy, -1, ny) + 1
            xx = np.clip(cx + k * dx, -1, nx) + 1
            at = code[yy, xx]
            found |= open_ & (at == 1)
            open_ &= at == 0
            if not open_.any():
                break
        hit[found] += (dx / norm, dy / norm)
        dirs += found
    is_edge = (np.linalg.norm(hit, axis=1) > 1e-9) & (dirs >= cfg.min_drop_dirs)
    iy, ix, dvec = cy[is_edge], cx[is_edge], hit[is_edge]
    g = emap.grid
    dvec /= np.linalg.norm(dvec, axis=1, keepdims=True)
    px = g.x0 + (ix + 0.5) * g.cell + 0.5 * g.cell * dvec[:, 0]
    py = g.y0 + (iy + 0.5) * g.cell + 0.5 * g.cell * dvec[:, 1]
    return EdgeCells(np.column_stack([px, py]), safe, code[1:-1, 1:-1] == 1)


def fit_polygon(emap: ElevationMap, cells: EdgeCells, cfg: EdgeConfig) -> EdgeModel:
    """Methods 4/5: non-convex polygon of the safe region; its edge part as lines (§2)."""
    return run_to_end(fit_polygon_steps(emap, cells, cfg))


def fit_polygon_steps(emap: ElevationMap, cells: EdgeCells, cfg: EdgeConfig) -> Generator[None, None, EdgeModel]:
    """:func:`fit_polygon` as a slack-job generator: it yields after the contour polygons,
    after their union and after each piece's edge runs (a slice each, not the whole fit)."""
    empty = EdgeModel("polygon", cells.points_xy, MultiLineString(), None)
    if cells.points_xy.shape[0] < 2:
        return empty
    g = emap.grid
    mask = cells.safe.astype(np.uint8)
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    polys = []
    for c in contours:
        if c.shape[0] < 3:
            continue
        xy = c.reshape(-1, 2).astype(np.float64)
        # contour vertices are boundary cell centres; push them half a cell outward later
        poly = Polygon(np.column_stack([g.x0 + (xy[:, 0] + 0.5) * g.cell,
                                        g.y0 + (xy[:, 1] + 0.5) * g.cell])).buffer(0)
        if not poly.is_empty:
            polys.append(poly.buffer(0.5 * g.cell, join_style="mitre"))
    if not polys:
        return empty
    yield None
    region = shapely.union_all(polys).simplify(cfg.simplify_m)
    geoms = list(getattr(region, "geoms", [region]))
    yield None
    edge_pts = shapely.points(cells.points_xy)
    tree = shapely.STRtree(edge_pts)
    runs = []
    for poly in geoms:
        poly = shapely.geometry.polygon.orient(poly, 1.0)  # CCW: inside on the left
        ring = densify_ring(np.asarray(poly.exterior.coords), g.cell)
        near = tree.query(shapely.points(ring), predicate="dwithin", distance=cfg.match_m)
        flag = np.zeros(ring.shape[0], bool)
        flag[np.unique(near[0])] = True
        runs += _runs(ring, flag, cfg)
        yield None
    # every piece of the plateau (one within join_m, separate contours) clips the extensions
    model_poly = geoms[0] if len(geoms) == 1 else MultiPolygon([p for p in geoms if isinstance(p, Polygon)])
    return EdgeModel("polygon", cells.points_xy, MultiLineString(runs), model_poly)


def _runs(ring: F64, flag: NDArray[np.bool_], cfg: EdgeConfig) -> list[LineString]:
    """Maximal runs of flagged vertices along a closed ring, as simplified lines. Runs less
    than ``BRIDGE_M`` apart along the ring are one run: a small spike or cleft of the polygon
    at the lip (a vertex just beyond ``match_m``) must not break the edge into pieces, each
    with a fresh end whose straight continuation (``EdgeModel.barrier``) cuts the plateau."""
    flag = bridge_runs(ring, flag, BRIDGE_M)
    if flag.all():
        return [LineString(ring).simplify(cfg.simplify_m)]
    start = int(np.argmin(flag))  # rotate so the ring starts on an unflagged vertex
    ring, flag = np.roll(ring[:-1], -start, axis=0), np.roll(flag[:-1], -start)
    edges = np.diff(np.concatenate([[0], flag.astype(np.int8), [0]]))
    out = []
    for a, b in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=True):
        if b - a >= 2:
            ln = LineString(ring[a:b]).simplify(cfg.simplify_m)
            if ln.length >= cfg.min_edge_len_m:
                out.append(ln)
    return out


def fit_line(cells: EdgeCells, safe_xy: tuple[float, float]) -> EdgeModel:
    """Method 3: the edge as one straight segment (total least squares), safe side on the left."""
    pts = cells.points_xy
    if pts.shape[0] < 2:
        return EdgeModel("line", pts, MultiLineString(), None)
    c = pts.mean(axis=0)
    _, _, vt = np.linalg.svd(pts - c, full_matrices=False)
    d = vt[0]
    s = (pts - c) @ d
    a, b = c + s.min() * d, c + s.max() * d
    to_safe = np.asarray(safe_xy, dtype=np.float64) - c
    if d[0] * to_safe[1] - d[1] * to_safe[0] < 0:  # safe point must be on the left
        a, b = b, a
    return EdgeModel("line", pts, MultiLineString([LineString([a, b])]), None)


def sample_lines(lines: MultiLineString, step_m: float) -> F64:
    out = []
    for ln in lines.geoms:
        n = max(2, int(np.ceil(ln.length / step_m)) + 1)
        out.append(shapely.get_coordinates(
            shapely.line_interpolate_point(ln, np.linspace(0.0, ln.length, n))))
    return np.concatenate(out) if out else np.zeros((0, 2))
