"""Methods 1 and 2 of docs/algorithm.md §7: the raster-scan baselines (the rows, stations and
tilt bands are described in ``fsw.core.planning.planners``)."""

from __future__ import annotations

import itertools
import math
from collections.abc import Generator, Iterable
from dataclasses import dataclass

import numpy as np
import shapely
from shapely.geometry import LineString, Point
from shapely.geometry.base import BaseGeometry

from fsw.core.geometry import CameraConfig, MastConfig, camera_pose_from_rover, wrap_angle
from fsw.core.planning.nbv import (
    NbvConfig,
)
from fsw.core.planning.planners import Planner, PlannerState, SearchGen
from fsw.core.planning.view_candidates import (
    CandidateView,
    Pose3,
    along_extent,
    as_polyline,
    footprint,
)
from fsw.core.planning.visibility import F64


@dataclass
class _Row:
    """One raster row: a pass along the path at one tilt band."""

    direction: float  # +1: along the path's own order, -1: against it
    joints: list[Pose3]  # the row's mast poses (Method 1: one; Method 2: the pan sweep)
    spacing_m: float
    stations: int  # stations allotted to the row
    band: int  # index in RasterPlanner.bands
    taken: int = 0  # stations placed so far


class RasterPlanner(Planner):
    """Methods 1 and 2 (see the module docstring)."""

    def __init__(self, sweep: bool, n_views: int, cfg: NbvConfig, camera: CameraConfig,
                 mast: MastConfig) -> None:
        self.sweep, self.n_views = sweep, int(n_views)
        self.cfg, self.camera, self.mast = cfg, camera, mast
        self.name = "2" if sweep else "1"
        self.spacing_m = 0.0  # the first row's station spacing
        self.bands: list[tuple[float, float]] = []  # (tilt rad, station spacing m), near to far
        self.rows: list[_Row] = []  # rows begun so far; the last is the current one
        self.given = 0  # views handed out
        self._ready = False
        self._pans: list[float] = []
        self._lift = 0.0
        self._heading_dir = 1.0  # the rover faces the first row's direction throughout
        self._last_xy: tuple[float, float] = (0.0, 0.0)  # the last station
        self._station: Pose3 | None = None
        self._sweep_i = 0

    @property
    def per_station(self) -> int:
        return len(self._pans) if self._pans else 1

    def search(self, state: PlannerState) -> SearchGen:
        if not self._ready:
            self._ready = True
            yield from self._setup(state)
        yield None
        while self._ready and self.given < self.n_views and self.rows:
            row = self.rows[-1]
            if self._station is not None and self._sweep_i < len(row.joints):
                return self._sweep_view(row, state)  # the rest of the station's pan sweep
            self._station = None
            if row.taken < row.stations:
                station = yield from self._next_station(row, state)
                if station is not None:
                    self._station, self._sweep_i = station, 0
                    row.taken += 1
                    continue
            if not self._next_row(state):
                return None
        return None

    def _sweep_view(self, row: _Row, state: PlannerState) -> CandidateView:
        assert self._station is not None
        rover = self._station
        if self._sweep_i > 0 and not _close(rover, state.rover) and not state.motion_ok(
                state.rover, rover):
            rover = state.rover  # already at the station: pan only
        view = CandidateView(rover, row.joints[self._sweep_i], method=self.name)
        self._sweep_i += 1
        self.given += 1
        return view

    def _line(self, state: PlannerState) -> LineString | None:
        """The edge path as now known, continued straight across the map at both ends."""
        xy = as_polyline(state.path)
        if xy.shape[0] < 2:
            return None
        return _extend_across_roi(_extend_across_roi(LineString(xy), True, state), False, state)

    def _setup(self, state: PlannerState) -> Generator[None, None, None]:
        """The operator's set-up, made once: direction, pointing, tilt bands, first row."""
        xy = as_polyline(state.path)
        if xy.shape[0] < 2 or self.n_views < 1:
            self._ready = False
            return
        known = LineString(xy)
        s_known = float(known.project(Point(state.rover[0], state.rover[1])))
        side0, t0 = _point_and_heading(known, s_known, 1.0)
        forward = _roi_reach(state, side0, t0) >= _roi_reach(state, side0, t0 + math.pi)
        direction = 1.0 if forward else -1.0
        # The operator scans the whole region of interest: the edge path as far as it is known,
        # then straight on to where it leaves the map (the edge is taken to go on, as the geofence does).
        line = self._line(state)
        assert line is not None
        s_now = float(line.project(Point(state.rover[0], state.rover[1])))
        remaining = line.length - s_now if forward else s_now
        side = _drop_side(line, s_now, direction, state.edge_xy)
        per_station = self.cfg.raster_pans_per_station if self.sweep else 1
        step = math.radians(self.camera.hfov_deg) * (1.0 - self.cfg.raster_overlap_frac)
        centre = side * math.pi / 2.0
        self._pans = [centre + (i - (per_station - 1) / 2.0) * step for i in range(per_station)]
        self._lift = self.mast.lift_max_m
        floor_z = _floor_estimate(state, self.cfg)
        start, tangent = _point_and_heading(line, s_now, direction)
        rover0 = (float(start[0]), float(start[1]), tangent)
        tilt = yield from best_floor_tilt_steps(rover0, centre, self._lift, floor_z,
                                                state.ground_z_m, self.camera, self.mast)
        tilt = min(tilt, lip_tilt(rover0, centre, self._lift, state, self.camera, self.mast))
        along = np.array([math.cos(tangent), math.sin(tangent)])
        across = np.array([math.cos(tangent + centre), math.sin(tangent + centre)])
        union = self._union(rover0, tilt, floor_z, state.ground_z_m)
        lo, hi = along_extent(union, start, along)
        fp_spacing = (hi - lo) * (1.0 - self.cfg.raster_overlap_frac)
        self.bands = [(tilt, fp_spacing)]
        self.bands += (yield from self._outer_bands(rover0, tilt, floor_z, state.ground_z_m,
                                                   start, along, across))
        n_stations = math.ceil(self.n_views / per_station)
        spacing = fp_spacing
        if n_stations > 1:
            spacing = min(spacing, remaining / (n_stations - 1))
        self.spacing_m = spacing
        self._heading_dir = direction
        self._last_xy = (float(start[0]), float(start[1]))
        self.rows = [_Row(direction, self._joints(tilt), spacing, n_stations, 0)]

    def _joints(self, tilt: float) -> list[Pose3]:
        return [self.mast.clamp(p, tilt, self._lift) for p in self._pans]

    def _union(self, rover: Pose3, tilt: float, floor_z: float, ground_z: float) -> BaseGeometry:
        return shapely.union_all([footprint(camera_pose_from_rover(rover, j, self.mast, ground_z),
                                            self.camera, floor_z) for j in self._joints(tilt)])

    def _outer_bands(self, rover: Pose3, tilt: float, floor_z: float, ground_z: float,
                     start: F64, along: F64, across: F64
                     ) -> Generator[None, None, list[tuple[float, float]]]:
        """The tilt bands beyond the first row's, each overlapping the one before by
        ``raster_overlap_frac`` of its width across the path; the bands end where a higher
        tilt would add less than a quarter of the previous band's width (range limit)."""
        overlap = self.cfg.raster_overlap_frac
        top = math.radians(min(self.mast.tilt_max_deg, 0.0))
        out: list[tuple[float, float]] = []
        lo_p, hi_p = along_extent(self._union(rover, tilt, floor_z, ground_z), start, across)
        while True:
            best: tuple[float, float, float] | None = None  # tilt, across extent lo, hi
            t = tilt + math.radians(1.0)
            while t <= top + 1e-9:
                lo, hi = along_extent(self._union(rover, t, floor_z, ground_z), start, across)
                yield None
                if hi > lo and lo <= hi_p - overlap * (hi_p - lo_p):
                    best = (t, lo, hi)
                t += math.radians(1.0)
            if best is None or best[2] - hi_p < 0.25 * (hi_p - lo_p):
                return out
            t, lo, hi = best
            # Spacing: the band's along-path width where it starts to be new ground (its
            # narrowest part not covered by the band before), less the overlap.
            cut = LineString([start + hi_p * across - 100.0 * along,
                              start + hi_p * across + 100.0 * along])
            union = self._union(rover, t, floor_z, ground_z)
            pts = shapely.get_coordinates(union.intersection(cut))
            if len(pts) == 0:
                pts = shapely.get_coordinates(union)
            proj = (pts - start) @ along
            out.append((t, float(proj.max() - proj.min()) * (1.0 - overlap)))
            tilt, lo_p, hi_p = t, lo, hi

    def _next_row(self, state: PlannerState) -> bool:
        """Begin the next row: back the other way along the path at the next tilt band out
        (after the farthest band, a new pass from the first), the stations left split evenly
        over the bands left in the pass, spread over the path to its far end (more overlap,
        never a gap). False if no views are left or there is no path."""
        line = self._line(state)
        left = math.ceil((self.n_views - self.given) / self.per_station)
        if line is None or left < 1 or not self.bands:
            return False
        prev = self.rows[-1]
        band = (prev.band + 1) % len(self.bands)
        direction = -prev.direction
        stations = math.ceil(left / (len(self.bands) - band))
        tilt, fp_spacing = self.bands[band]
        s_now = float(line.project(Point(state.rover[0], state.rover[1])))
        length = line.length - s_now if direction > 0 else s_now
        spacing = fp_spacing if stations < 2 else min(fp_spacing, length / (stations - 1))
        self._last_xy = (float(state.rover[0]), float(state.rover[1]))
        self._station = None
        self.rows.append(_Row(direction, self._joints(tilt), spacing, stations, band))
        return True

    def _next_station(self, row: _Row, state: PlannerState) -> Generator[None, None, Pose3 | None]:
        """The row's next station: one spacing on from the last along the path as now known;
        if the geofence refuses the move there, the farthest reachable point toward it, at
        least a quarter spacing on (the operator advances as far as is safe and the view
        reveals the edge ahead); None when the path's end or the reachable part is used up."""
        line = self._line(state)
        if line is None:
            return None
        s_last = float(line.project(Point(*self._last_xy)))
        if row.taken == 0:
            if len(self.rows) > 1:  # a new row starts where the last one ended
                return state.rover
            # The first row starts at the rover's projection on the path, or if the geofence
            # refuses that, at the nearest path point on in the row's direction it allows
            # (within one spacing; e.g. the projection's footprint leaves the map).
            first = (min(line.length, max(0.0, s_last + row.direction * 0.05 * k))
                     for k in range(int(row.spacing_m / 0.05) + 1))
            st = yield from self._first_reachable(line, first, state)
            if st is not None:
                return st
            self._last_xy = (state.rover[0], state.rover[1])
            return state.rover
        d = row.direction
        s_target = min(line.length, max(0.0, s_last + d * row.spacing_m))
        min_advance = max(row.spacing_m / 4.0, 1e-3)
        back = itertools.takewhile(lambda s: d * (s - s_last) >= min_advance - 1e-9,
                                   (s_target - d * 0.05 * k for k in itertools.count()))
        return (yield from self._first_reachable(line, back, state))

    def _first_reachable(self, line: LineString, arcs: Iterable[float], state: PlannerState
                         ) -> Generator[None, None, Pose3 | None]:
        """The station at the first arc length along ``line`` that the geofence lets the rover
        reach (yielding after each check), remembered as the last station; None if none."""
        for s in arcs:
            p, yaw = _point_and_heading(line, s, self._heading_dir)
            st = (float(p[0]), float(p[1]), yaw)
            ok = _close(st, state.rover) or state.motion_ok(state.rover, st)
            yield None
            if ok:
                self._last_xy = (st[0], st[1])
                return st
        return None

def best_floor_tilt_steps(rover: Pose3, pan: float, lift: float, floor_z_m: float,
                          ground_z_m: float, camera: CameraConfig, mast: MastConfig
                          ) -> Generator[None, None, float]:
    """The tilt (1 deg grid within limits) whose footprint on the floor plane is largest;
    yields after each tilt (a slack-job step)."""
    tilts = np.radians(np.arange(mast.tilt_min_deg, min(mast.tilt_max_deg, 0.0) + 1e-9, 1.0))
    areas = []
    for t in tilts:
        areas.append(footprint(camera_pose_from_rover(rover, (pan, float(t), lift), mast,
                                                      ground_z_m), camera, floor_z_m).area)
        yield None
    return float(tilts[int(np.argmax(areas))])


def lip_tilt(rover: Pose3, pan: float, lift: float, state: PlannerState, camera: CameraConfig,
             mast: MastConfig, margin_m: float = 0.1) -> float:
    """The tilt that keeps the edge lip (the nearest fitted edge point, less ``margin_m``) just
    inside the bottom of the image, so each raster view also maps the edge it drives along."""
    if state.edge_xy is None or len(state.edge_xy) == 0:
        return 0.0
    cam = camera_pose_from_rover(rover, (pan, 0.0, lift), mast, state.ground_z_m).t
    dist = float(np.min(np.hypot(state.edge_xy[:, 0] - cam[0], state.edge_xy[:, 1] - cam[1])))
    depression = math.atan2(cam[2] - state.ground_z_m, max(dist - margin_m, 0.05))
    return float(np.clip(camera.vfov_rad / 2.0 - depression, math.radians(mast.tilt_min_deg),
                         math.radians(mast.tilt_max_deg)))


def _floor_estimate(state: PlannerState, cfg: NbvConfig) -> float:
    z = state.map.z
    low = z[np.isfinite(z) & (z < state.ground_z_m - 0.1)]
    if low.size >= 100:
        return float(np.median(low))
    return state.ground_z_m - cfg.raster_floor_drop_m


def _roi_reach(state: PlannerState, start: F64, heading: float) -> float:
    """How far the map (the region of interest) reaches from ``start`` along ``heading``."""
    g = state.map.grid
    xs, ys = (g.x0, g.x0 + g.nx * g.cell), (g.y0, g.y0 + g.ny * g.cell)
    corners = np.array([(x, y) for x in xs for y in ys]) - np.asarray(start, dtype=np.float64)
    return float(max(0.0, (corners @ np.array([math.cos(heading), math.sin(heading)])).max()))


def _roi_exit(state: PlannerState, start: F64, heading: float) -> float:
    """How far a ray from ``start`` along ``heading`` runs before it leaves the map's rectangle
    (0 if it does not run inside it)."""
    g = state.map.grid
    lo = np.array([g.x0, g.y0])
    hi = lo + np.array([g.nx, g.ny]) * g.cell
    d = np.array([math.cos(heading), math.sin(heading)])
    p = np.asarray(start, dtype=np.float64)
    t0, t1 = 0.0, math.inf
    for k in range(2):
        if abs(d[k]) < 1e-12:
            if not lo[k] <= p[k] <= hi[k]:
                return 0.0
            continue
        a, b = (lo[k] - p[k]) / d[k], (hi[k] - p[k]) / d[k]
        t0, t1 = max(t0, min(a, b)), min(t1, max(a, b))
    return float(t1) if t1 > t0 else 0.0


def _extend_across_roi(line: LineString, forward: bool, state: PlannerState) -> LineString:
    """The path continued straight past its end (in the travel direction) to where it leaves
    the map's rectangle."""
    c = np.asarray(line.coords)
    end, prev = (c[-1], c[-2]) if forward else (c[0], c[1])
    d = end - prev
    heading = math.atan2(d[1], d[0])
    reach = _roi_exit(state, end, heading)
    if reach <= 0.0:
        return line
    tip = end + reach * np.array([math.cos(heading), math.sin(heading)])
    return LineString(np.vstack([c, tip]) if forward else np.vstack([tip, c]))


def _drop_side(line: LineString, s: float, direction: float, edge_xy: F64 | None) -> float:
    """+1 if the drop is left of the travel direction, -1 if right."""
    if edge_xy is not None and len(edge_xy) > 0:
        p, yaw = _point_and_heading(line, s, direction)
        q = shapely.get_coordinates(shapely.shortest_line(Point(p), shapely.multipoints(
            np.asarray(edge_xy, dtype=np.float64)[:, :2])))[-1]
        cross = math.cos(yaw) * (q[1] - p[1]) - math.sin(yaw) * (q[0] - p[0])
        return 1.0 if cross > 0 else -1.0
    return -direction  # edge.edge_path convention: the edge is right of the path direction


def _tangent(line: LineString, s: float) -> float:
    a = line.interpolate(max(0.0, min(line.length, s - 0.01)))
    b = line.interpolate(max(0.0, min(line.length, s + 0.01)))
    return math.atan2(b.y - a.y, b.x - a.x)


def _point_and_heading(line: LineString, s: float, direction: float) -> tuple[F64, float]:
    s = max(0.0, min(line.length, s))
    p = line.interpolate(s)
    yaw = _tangent(line, s) + (0.0 if direction > 0 else math.pi)
    return np.array([p.x, p.y]), wrap_angle(yaw)


def _close(a: Pose3, b: Pose3) -> bool:
    return math.hypot(a[0] - b[0], a[1] - b[1]) < 1e-6 and abs(
        math.remainder(a[2] - b[2], 2 * math.pi)) < 1e-6
