"""Candidate views: rover stations along the edge path times a mast pan/tilt/lift grid (§3).

A candidate is 5-DOF plus heading: the rover pose ``(x, y, yaw)`` on the edge-following path
(docs/algorithm.md §2; ``fsw.core.edge.edge.edge_path`` makes it) and the mast joints ``(pan, tilt,
lift)`` within ``MastConfig`` limits. Stations are spaced ``station_spacing_m`` along the
path up to ``max_travel_m`` either way from the rover's projection on it (a path sample
within half a spacing of the rover is the rover's own station, not a move). A station is kept
only if the rover can get there: every leg from the current pose, station by station along
the path, must pass the geofence (``motion_ok(a, b)``, e.g.
``lambda a, b: geofence.check(a, b).allowed``). The rover's current pose is always a station
(pan/tilt-only moves). A station's heading is the path tangent, flipped by pi if that is
closer to the current heading (the rover may drive either way along the path).

A rover standing off the path (farther than half a station spacing: the edge runs closer to
or farther from it than the path's setback) also gets stations straight ahead and behind it,
at the same spacing, keeping its heading: reaching the path needs a turn in place, whose
swinging corners the geofence may refuse near the edge (or over ground no look can map),
while a straight drive sweeps only the wheels' own tracks (issue 13 item 3).

A rover boxed in by a close edge (the first station along the path refused both ways: the turn
toward the path would swing its wheels within the margin) gets the moves that free it (issue 30
item 1): straight back or ahead keeping its heading (a drive sweeps only the wheels' tracks,
and from a station set back from the edge the turn is allowed) and a turn in place to the path's
heading either way, each if the geofence allows it; these stations are marked ``escape``.

With no edge path (no edge mapped yet: the views from the start did not reach the drop), the
stations are the edge search's: along eight directions around the rover, as far as the
geofence allows (with no edge fitted, wheels keep the margin from every mapped drop cell).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Generator
from dataclasses import dataclass

import numpy as np
import shapely
from shapely.geometry import LineString, MultiPoint, Point, Polygon

from fsw.core.geometry import CameraConfig, CameraPose, MastConfig, camera_pose_from_rover, wrap_angle
from fsw.core.planning.visibility import F64
from fsw.core.steps import run_to_end

Pose3 = tuple[float, float, float]
SEARCH_HEADINGS = 8  # the edge search's directions around the rover
TURN_MIN_RAD = math.radians(10.0)  # a turn in place less than this is no move (the mission's MIN_TURN_RAD)
MotionCheck = Callable[[Pose3, Pose3], bool]


@dataclass(frozen=True)
class CandidateView:
    """A view to take: rover pose, mast joints and, for rated planners, its rating (§3.5)."""

    rover: Pose3  # x, y (m), yaw (rad)
    joints: Pose3  # pan, tilt (rad), lift (m)
    info_bits: float = 0.0  # H(c), Eq 3
    expected_new_cells: float = 0.0
    motion_cost: float = 0.0  # d(c, c_now), Eq 9
    sigma_loc_m: float = 0.0
    utility: float = 0.0
    method: str = ""
    note: str = ""  # why the rover stays, when it must (boxed in with no move the geofence allows)

    def camera_pose(self, mast: MastConfig, ground_z_m: float = 0.0) -> CameraPose:
        return camera_pose_from_rover(self.rover, self.joints, mast, ground_z_m)

    @property
    def pose6(self) -> F64:
        return np.array([*self.rover, *self.joints], dtype=np.float64)


@dataclass(frozen=True)
class Station:
    """A reachable rover pose and the path distance to it."""

    rover: Pose3
    travel_m: float
    escape: bool = False  # a move that frees a rover boxed in by a close edge (no path station reachable)




def as_polyline(path: F64) -> F64:
    """``(N, 2)`` x, y of a path given as (N, 2) or (N, 3) rows, duplicate points removed."""
    p = np.asarray(path, dtype=np.float64)
    if p.size == 0:
        return np.zeros((0, 2))
    if p.ndim != 2 or p.shape[1] not in (2, 3) or not np.isfinite(p).all():
        raise ValueError(f"a path must be finite (N, 2) or (N, 3) rows, got shape {p.shape}")
    p = p[:, :2]
    if p.shape[0] < 2:
        return p
    keep = np.concatenate([[True], np.hypot(*np.diff(p, axis=0).T) > 1e-9])
    return p[keep]


def sample_path(xy: F64, spacing_m: float) -> tuple[F64, F64, F64]:
    """Points every ``spacing_m`` along a polyline: ``(arc length, xy, tangent yaw)``."""
    seg = np.diff(xy, axis=0)
    s_knots = np.concatenate([[0.0], np.cumsum(np.hypot(seg[:, 0], seg[:, 1]))])
    s = np.arange(0.0, s_knots[-1] + 1e-9, spacing_m)
    pts = np.column_stack([np.interp(s, s_knots, xy[:, 0]), np.interp(s, s_knots, xy[:, 1])])
    k = np.clip(np.searchsorted(s_knots, s, side="right") - 1, 0, len(seg) - 1)
    return s, pts, np.arctan2(seg[k, 1], seg[k, 0])


def _heading(tangent: float, current: float) -> float:
    flip = math.cos(tangent - current) < 0.0
    return wrap_angle(tangent + math.pi * flip)


def path_stations(path: F64, rover_now: Pose3, motion_ok: MotionCheck, spacing_m: float,
                  max_travel_m: float) -> list[Station]:
    """Reachable, geofence-checked stations along ``path`` (see the module docstring)."""
    return run_to_end(path_stations_steps(path, rover_now, motion_ok, spacing_m, max_travel_m))


def path_stations_steps(path: F64, rover_now: Pose3, motion_ok: MotionCheck, spacing_m: float,
                        max_travel_m: float) -> Generator[None, None, list[Station]]:
    """:func:`path_stations`, yielding after each geofence check (one check a slice)."""
    now = Station((float(rover_now[0]), float(rover_now[1]), float(rover_now[2])), 0.0)
    xy = as_polyline(path)
    if xy.shape[0] < 2:  # no edge path yet: the edge search (stations the geofence allows)
        return [now] + (yield from search_stations_steps(now.rover, motion_ok, spacing_m, max_travel_m))
    line = LineString(xy)
    s_now = float(line.project(Point(rover_now[0], rover_now[1])))
    off_m = float(line.distance(Point(rover_now[0], rover_now[1])))
    s, pts, tangent = sample_path(xy, spacing_m)
    # A sample within half a spacing of the rover is where it stands (its own station): driving
    # a few cm to it would only turn the rover in place, and a refused turn there must not
    # hide the stations beyond it.
    here = np.hypot(pts[:, 0] - rover_now[0], pts[:, 1] - rover_now[1]) < spacing_m / 2.0
    out = [now]
    blocked = 0  # directions along the path whose first station is refused
    for direction in (1.0, -1.0):
        sel = np.flatnonzero((direction * (s - s_now) > 1e-6) & ~here
                             & (np.abs(s - s_now) <= max_travel_m))
        sel = sel[np.argsort(direction * s[sel])]
        prev = now.rover
        blocked += int(sel.size > 0)
        for i in sel:
            st = (float(pts[i, 0]), float(pts[i, 1]), _heading(float(tangent[i]), rover_now[2]))
            # The hop along the path, and the straight move the mission will command from here:
            # one geofence check a slice (a check of a long move is itself up to ~25 ms here).
            ok = motion_ok(prev, st)
            if ok and prev != now.rover:
                yield None
                ok = motion_ok(now.rover, st)
            yield None
            if not ok:
                break
            blocked -= int(prev == now.rover)
            out.append(Station(st, abs(float(s[i]) - s_now) + off_m))
            prev = st
    boxed = len(out) == 1 and blocked > 0
    if off_m > spacing_m / 2.0 or boxed:
        out += [Station(st.rover, st.travel_m, boxed)
                for st in (yield from straight_stations_steps(now.rover, motion_ok, spacing_m, max_travel_m))]
    if boxed:
        k = int(np.argmin(np.abs(s - s_now)))
        for yaw in (float(tangent[k]), wrap_angle(float(tangent[k]) + math.pi)):
            turned = (now.rover[0], now.rover[1], yaw)
            if abs(wrap_angle(yaw - now.rover[2])) >= TURN_MIN_RAD and motion_ok(now.rover, turned):
                out.append(Station(turned, 0.0, True))
            yield None
    return out


def search_stations_steps(rover_now: Pose3, motion_ok: MotionCheck, spacing_m: float,
                          max_travel_m: float, headings: int = SEARCH_HEADINGS
                          ) -> Generator[None, None, list[Station]]:
    """The edge search (no edge mapped yet, docs/algorithm.md §2): stations every ``spacing_m`` up
    to ``max_travel_m`` along ``headings`` directions around the rover (the first its own
    heading), each facing the way it was driven, each ray until the first the geofence
    refuses (with no edge fitted it keeps the wheels the margin from every mapped drop cell,
    ``fsw.core.edge.geofence``)."""
    x, y, yaw = rover_now
    out = []
    for k in range(headings):
        h = math.remainder(yaw + k * math.tau / headings, math.tau)
        c, s = math.cos(h), math.sin(h)
        for j in range(1, int(math.floor(max_travel_m / spacing_m + 1e-9)) + 1):
            st = (x + j * spacing_m * c, y + j * spacing_m * s, h)
            ok = motion_ok(rover_now, st)
            yield None
            if not ok:
                break
            out.append(Station(st, j * spacing_m))
    return out


def straight_stations_steps(rover_now: Pose3, motion_ok: MotionCheck, spacing_m: float,
                            max_travel_m: float) -> Generator[None, None, list[Station]]:
    """Stations every ``spacing_m`` straight ahead of and behind the rover, its heading kept,
    up to ``max_travel_m``, each way until the first the geofence refuses."""
    x, y, yaw = rover_now
    c, s = math.cos(yaw), math.sin(yaw)
    out = []
    for direction in (1.0, -1.0):
        for k in range(1, int(math.floor(max_travel_m / spacing_m + 1e-9)) + 1):
            t = direction * k * spacing_m
            st = (x + t * c, y + t * s, yaw)
            ok = motion_ok(rover_now, st)
            yield None
            if not ok:
                break
            out.append(Station(st, abs(t)))
    return out


def joint_grid(mast: MastConfig, pan_step_deg: float, tilts_deg: tuple[float, ...],
               lifts_m: tuple[float, ...]) -> tuple[F64, F64, F64]:
    """Pan (rad), tilt (rad) and lift (m) values within the mast limits."""
    pans = np.radians(np.arange(mast.pan_min_deg, mast.pan_max_deg + 1e-9, pan_step_deg))
    tilts = np.radians([t for t in tilts_deg if mast.tilt_min_deg <= t <= mast.tilt_max_deg])
    lifts = np.array([v for v in lifts_m if mast.lift_min_m <= v <= mast.lift_max_m])
    if tilts.size == 0 or lifts.size == 0:
        raise ValueError("no tilt or lift of the candidate grid lies within the mast limits")
    return pans, tilts, lifts


def footprint(pose: CameraPose, camera: CameraConfig, plane_z_m: float) -> Polygon:
    """Where the view's frustum between min and max range meets the plane ``z = plane_z_m``
    (empty polygon if it does not). Used to space the raster baselines (§7)."""
    th = math.tan(math.radians(camera.hfov_deg) / 2.0)
    tv = math.tan(camera.vfov_rad / 2.0)
    corners = np.array([[-th, -tv, 1.0], [th, -tv, 1.0], [th, tv, 1.0], [-th, tv, 1.0]])
    near = pose.camera_to_world(corners * camera.min_range_m)
    far = pose.camera_to_world(corners * camera.max_range_m)
    verts = np.vstack([near, far])
    edges = [(i, (i + 1) % 4) for i in range(4)] + [(4 + i, 4 + (i + 1) % 4) for i in range(4)]
    edges += [(i, i + 4) for i in range(4)]
    hits = []
    for a, b in edges:
        za, zb = verts[a, 2] - plane_z_m, verts[b, 2] - plane_z_m
        if za == 0.0:
            hits.append(verts[a, :2])
        if za * zb < 0.0:
            hits.append(verts[a, :2] + (za / (za - zb)) * (verts[b, :2] - verts[a, :2]))
    if len(hits) < 3:
        return Polygon()
    hull = MultiPoint([tuple(h) for h in hits]).convex_hull
    return hull if isinstance(hull, Polygon) else Polygon()


def along_extent(poly: Polygon, origin: F64, direction: F64) -> tuple[float, float]:
    """``(min, max)`` of a polygon's projection on a line through ``origin`` along ``direction``."""
    if poly.is_empty:
        return (0.0, 0.0)
    pts = shapely.get_coordinates(poly) - origin
    proj = pts @ (np.asarray(direction) / np.linalg.norm(direction))
    return float(proj.min()), float(proj.max())
