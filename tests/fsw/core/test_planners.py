"""The §7 planners: raster baselines' spacing and overlap, information planners, safety."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import shapely
from shapely.geometry import LineString, MultiLineString

from fsw.core.edge.edge import EdgeModel, edge_path
from fsw.core.edge.geofence import Geofence, GeofenceConfig
from fsw.core.geometry import CameraConfig, MapGrid, MastConfig, RoverConfig, camera_pose_from_rover
from fsw.core.map.elevation_map import ElevationMap
from fsw.core.planning.info_planners import InformationPlanner, straighten
from fsw.core.planning.methods import make_planner
from fsw.core.planning.nbv import NbvConfig
from fsw.core.planning.planners import PlannerState
from fsw.core.planning.raster_planners import RasterPlanner, _close
from fsw.core.planning.view_candidates import CandidateView, along_extent, footprint, path_stations
from fsw.core.planning.visibility import cell_points, in_view, terrain_from_map
from hil_sim.lab.nbv_scene import edge_offset_path, panorama_map, synthetic_edge, synthetic_terrain

GRID = MapGrid(x0=-0.5, y0=-3.5, cell=0.04, nx=110, ny=100)
CAM, MAST = CameraConfig(), MastConfig()
FAST = NbvConfig(max_travel_m=1.0, pan_step_deg=30.0, tilts_deg=(-30.0, -50.0))


def _ok(a: tuple, b: tuple) -> bool:
    return True


def _straight_state(length_m: float) -> PlannerState:
    emap = ElevationMap(MapGrid(0.0, -4.0, 0.1, 20, 20))
    path = np.array([[0.0, 0.0], [length_m, 0.0]])
    edge = np.array([[0.0, -0.75], [length_m, -0.75]])
    return PlannerState(emap, (0.0, 0.0, 0.0), (0.0, 0.0, 0.5), path, _ok, edge_xy=edge)


def _run(planner, state: PlannerState, n: int) -> list[CandidateView]:
    out = []
    for _ in range(n):
        v = planner.next_view(state)
        if v is None:
            break
        out.append(v)
        state = PlannerState(state.map, v.rover, v.joints, state.path, state.motion_ok,
                             state.edge_xy, state.ground_z_m)
    return out


def _along_footprints(views: list[CandidateView], floor_z: float) -> list[tuple[float, float]]:
    return [along_extent(footprint(v.camera_pose(MAST), CAM, floor_z), np.zeros(2),
                         np.array([1.0, 0.0])) for v in views]


def test_raster_without_yaw_spacing_and_overlap() -> None:
    """Issue 5 item 3, Method 1: equally spaced stations whose consecutive views overlap by
    ``raster_overlap_frac`` of the footprint along the path; fixed mast pointing square to the
    path toward the drop, lift at maximum; exactly n views."""
    cfg = NbvConfig(raster_overlap_frac=0.1)
    planner = RasterPlanner(False, 5, cfg, CAM, MAST)
    views = _run(planner, _straight_state(40.0), 8)
    assert len(views) == 5
    xs = np.array([v.rover[0] for v in views])
    assert np.allclose(np.diff(xs), planner.spacing_m) and planner.spacing_m > 1.0
    assert {v.joints for v in views} == {views[0].joints}
    pan, tilt, lift = views[0].joints
    assert pan == pytest.approx(-math.pi / 2) and tilt < 0 and lift == MAST.lift_max_m
    ext = _along_footprints(views, -cfg.raster_floor_drop_m)
    width = ext[0][1] - ext[0][0]
    for (_, hi), (lo, _) in zip(ext[:-1], ext[1:], strict=True):
        assert (hi - lo) / width == pytest.approx(cfg.raster_overlap_frac, abs=0.01)


def test_raster_with_yaw_sweeps_pan_and_spaces_the_sweeps() -> None:
    """Issue 5 item 3, Method 2: pans_per_station pan views at each station, pan step
    hfov (1 - overlap); the sweeps' union footprints overlap by the same fraction."""
    cfg = NbvConfig(raster_overlap_frac=0.1, raster_pans_per_station=3)
    planner = RasterPlanner(True, 9, cfg, CAM, MAST)
    views = _run(planner, _straight_state(60.0), 12)
    assert len(views) == 9
    pans = np.array([v.joints[0] for v in views]).reshape(3, 3)
    step = math.radians(CAM.hfov_deg) * 0.9
    assert np.allclose(np.diff(pans, axis=1), step) and np.allclose(pans[:, 1], -math.pi / 2)
    xs = np.array([v.rover[0] for v in views]).reshape(3, 3)
    assert np.allclose(xs, xs[:, :1]) and np.allclose(np.diff(xs[:, 0]), planner.spacing_m)
    ext = _along_footprints(views, -cfg.raster_floor_drop_m)
    union = [(min(e[0] for e in ext[3 * k:3 * k + 3]), max(e[1] for e in ext[3 * k:3 * k + 3]))
             for k in range(3)]
    width = union[0][1] - union[0][0]
    assert (union[0][1] - union[1][0]) / width == pytest.approx(0.1, abs=0.01)


def test_raster_spacing_shrinks_to_fit_the_path() -> None:
    """Issue 5 item 3: on a short path the n stations are spread over it (more overlap,
    never past its end)."""
    planner = RasterPlanner(False, 5, NbvConfig(), CAM, MAST)
    views = _run(planner, _straight_state(3.0), 5)
    assert [round(v.rover[0], 6) for v in views] == [0.0, 0.75, 1.5, 2.25, 3.0]


def _synthetic_state(motion_ok=_ok) -> PlannerState:
    truth, textured = synthetic_terrain(GRID, seed=7)
    emap = panorama_map(truth, textured, GRID, CAM, MAST, (0.0, 0.0, 0.0))
    edge = synthetic_edge(-0.5, 3.9)
    return PlannerState(emap, (0.0, 0.0, 0.0), (0.0, 0.0, 0.5),
                        edge_offset_path(edge, 0.75), motion_ok, edge_xy=edge)


def _fence(a: tuple, b: tuple) -> bool:
    """A stand-in geofence: no pose beyond x = 1.3 m or below y = -0.35 m."""
    return b[0] <= 1.3 and b[1] >= -0.35


@pytest.mark.parametrize("method", ["1", "2", "3", "4", "5"])
def test_planners_never_propose_unsafe_or_unreachable_poses(method: str) -> None:
    """Issue 5 item 3: every proposed pose passes the geofence from where the rover is and
    its joints are within the mast limits."""
    state = _synthetic_state(_fence)
    planner = make_planner(method, 6, FAST, CAM, MAST)
    views = _run(planner, state, 6)
    assert views, "the planner found nothing to do"
    rover = state.rover
    for v in views:
        assert v.rover == rover or _fence(rover, v.rover)
        assert MAST.within_limits(*v.joints)
        rover = v.rover


def test_information_planner_rates_and_prefers_new_terrain() -> None:
    """Issue 5 items 1, 3: Method 4 picks a reachable view with positive H and expected new
    cells; the search yields in small steps (issue 5 item 5: slack job); it is deterministic."""
    state = _synthetic_state()
    planner = make_planner("4", 1, FAST, CAM, MAST)
    gen = planner.search(state)
    yields = 0
    try:
        while True:
            next(gen)
            yields += 1
    except StopIteration as stop:
        view = stop.value
    assert planner.last_stations >= 3
    # bounded steps: at least one per geofence check, chunk of rays and tilt of each centre
    assert yields >= planner.last_centres * (1 + len(FAST.tilts_deg)) + planner.last_stations - 1
    assert view.info_bits > 50 and view.expected_new_cells > 20
    assert view.utility == pytest.approx(view.info_bits - FAST.w_motion * view.motion_cost
                                         - FAST.w_loc * view.sigma_loc_m)
    assert make_planner("4", 1, FAST, CAM, MAST).next_view(state) == view


def test_interest_function_steers_method5_away_from_a_missed_region() -> None:
    """§3.4 / Method 5: when a region's interest has decayed, Method 5 looks elsewhere while
    Method 4 keeps looking at it."""
    state = _synthetic_state()
    v4 = make_planner("4", 1, FAST, CAM, MAST).next_view(state)
    terrain = terrain_from_map(state.map.z, state.map.var, GRID, FAST.visibility)
    iy, ix = np.nonzero(np.ones(GRID.shape, bool))
    seen4 = in_view(v4.camera_pose(MAST), CAM, cell_points(terrain, iy, ix)).reshape(GRID.shape)
    state.map.interest[seen4 & ~state.map.mapped] = 0.01
    v5 = make_planner("5", 1, FAST, CAM, MAST).next_view(state)
    seen5 = in_view(v5.camera_pose(MAST), CAM, cell_points(terrain, iy, ix)).reshape(GRID.shape)
    assert (seen5 & seen4).sum() < 0.5 * seen4.sum()


def test_oracle_needs_truth_and_rates_with_it() -> None:
    """Oracle planner: refuses to run without the truth; with it, rates textured cells only."""
    with pytest.raises(ValueError, match="true terrain"):
        make_planner("oracle", 1, FAST, CAM, MAST)
    with pytest.raises(ValueError, match="unknown method"):
        make_planner("7", 1, FAST, CAM, MAST)
    truth, textured = synthetic_terrain(GRID, seed=7)
    oracle = make_planner("oracle", 1, FAST, CAM, MAST, truth_z_m=truth, textured=textured)
    assert isinstance(oracle, InformationPlanner)
    view = oracle.next_view(_synthetic_state())
    assert view is not None and view.expected_new_cells > 20


def test_stations_follow_the_path_and_stop_at_the_geofence() -> None:
    """§3 candidates: stations every station_spacing_m within max_travel_m, headings along the
    path (closest to the current heading), none past a refused leg; the current pose first."""
    path = np.array([[0.0, 0.0], [4.0, 0.0]])
    st = path_stations(path, (1.0, 0.1, math.pi), lambda a, b: b[0] <= 2.0, 0.25, 1.5)
    assert st[0].rover == (1.0, 0.1, math.pi) and st[0].travel_m == 0.0
    xs = sorted(s.rover[0] for s in st[1:])
    assert xs[0] == pytest.approx(0.0) and xs[-1] == pytest.approx(2.0)
    assert all(abs(abs(s.rover[2]) - math.pi) < 1e-9 for s in st[1:])
    assert path_stations(np.zeros((0, 2)), (0.0, 0.0, 0.0), _ok, 0.25, 1.0)[0].travel_m == 0.0


def test_a_refused_turn_where_the_rover_stands_does_not_hide_the_stations_beyond() -> None:
    """Lab seed 1: the path sample 2 cm from the rover asks for a 16 deg turn in place that the
    geofence refuses (a rear corner swings toward the edge); the stations beyond, reachable by
    a straight drive, were lost with it. The sample where the rover stands is its own station."""
    path = np.array([[-0.98, 0.0], [0.3, 0.0], [3.0, 0.08]])  # a sample at x = 0.02

    def ok(a: tuple[float, float, float], b: tuple[float, float, float]) -> bool:
        return math.hypot(b[0] - a[0], b[1] - a[1]) > 0.1  # refuses every turn in place

    st = path_stations(path, (0.0, 0.0, 0.0), ok, 0.25, 1.5)
    xs = sorted(s.rover[0] for s in st[1:] if s.rover[0] > 0.0)
    assert xs and xs[0] > 0.1 and xs[-1] > 1.0
    assert all(math.hypot(s.rover[0], s.rover[1]) >= 0.125 for s in st[1:])


def test_method3_straightens_the_edge_path() -> None:
    """Method 3: the edge path becomes one total-least-squares segment spanning it."""
    path = edge_offset_path(synthetic_edge(-0.5, 3.9), 0.75)
    seg = straighten(path)
    assert seg.shape == (2, 2)
    d = seg[1] - seg[0]
    assert d[0] > 0 and abs(d[1]) < 0.2 * d[0]


def test_camera_pose_of_a_view_uses_the_mast_model() -> None:
    """A CandidateView's camera pose is geometry.camera_pose_from_rover of its pose."""
    v = CandidateView((1.0, 2.0, 0.3), (0.2, -0.4, 0.25))
    ref = camera_pose_from_rover((1.0, 2.0, 0.3), (0.2, -0.4, 0.25), MAST)
    assert np.allclose(v.camera_pose(MAST).t, ref.t) and np.allclose(v.camera_pose(MAST).R, ref.R)


def _lab_edge(x_max: float) -> np.ndarray:
    """The lab scenario's step edge (config/scenarios/lab.toml, without the wiggle): y = -0.8
    from x = -0.5 to 7, with the bay cut 0.3 m into the plateau at x = 3.3 (0.9 m wide),
    clipped at ``x_max`` (the part the views have seen)."""
    pts = [(-0.5, -0.8), (2.85, -0.8), (2.85, -0.5), (3.75, -0.5), (3.75, -0.8), (7.0, -0.8)]
    line = LineString(pts)
    clip = line.intersection(shapely.box(-10.0, -10.0, max(x_max, -0.4), 10.0))
    return np.asarray(getattr(clip, "geoms", [clip])[0].coords)


@pytest.mark.parametrize("sweep", [False, True])
def test_raster_on_the_lab_edge_uses_every_step_and_passes_the_geofence(sweep: bool) -> None:
    """Issue: the raster baselines get the same number of imaging steps as the other methods.
    A closed loop on the lab's edge shape with the real geofence and edge path: each view
    reveals the edge up to 0.8 m past the camera's station; the geofence takes the edge to go
    on straight past the revealed end (``extend_m``) and refuses stations beyond it (the bay's
    corner holds the rover back until seen). The raster yields a view for every one of its
    steps, each move allowed by the geofence from where the rover stood (or no move), and
    advances past the bay."""
    gf = Geofence(GeofenceConfig(), RoverConfig())
    emap = ElevationMap(MapGrid(-0.5, -6.5, 0.03, 256, 256))
    n = 20
    planner = RasterPlanner(sweep, n, NbvConfig(), CAM, MAST)
    rover, seen, views, reasons = (0.0, 0.0, 0.0), 0.8, [], []
    for _ in range(n + 3):
        edge = _lab_edge(seen)
        model = EdgeModel("polygon", edge, MultiLineString([edge]), None)
        gf.set_edge(model)
        state = PlannerState(emap, rover, (0.0, 0.0, 0.5), edge_path(model, 0.75, 0.25),
                             lambda a, b: gf.check(a, b).allowed, edge_xy=edge)
        v = planner.next_view(state)
        if v is None:
            break
        verdict = None if _close(v.rover, rover) else gf.check(rover, v.rover)
        assert verdict is None or verdict.allowed
        reasons.append("" if verdict is None else verdict.reason)
        assert MAST.within_limits(*v.joints)
        views.append(v)
        rover = v.rover
        seen = max(seen, rover[0] + 0.8)
    assert len(views) == n
    pans = {round(v.joints[0], 9) for v in views}
    assert len(pans) == (3 if sweep else 1)  # Method 1 never pans; Method 2 sweeps 3 pans
    # advancing as far as is safe carries row 1 past the bay to the pit's end
    assert max(v.rover[0] for v in views) > 3.75 + 2.0 and len(planner.rows) == 1
    if sweep:  # the sweep's longer spacing parks it beside the bay's corner, inside the margin
        # once the corner is seen: the geofence lets it out of the margin, never closer
        assert any("recovering" in r for r in reasons)


def test_rover_off_the_path_also_gets_straight_stations() -> None:
    """A rover farther than half a spacing from the path (issue 13 item 3: the edge closer than
    the setback) gets stations straight ahead and behind, its heading kept, each way up to the
    first refused one; a rover on the path gets none."""
    path = np.array([[-3.0, -0.5], [3.0, -0.5]])
    rover = (0.0, 0.0, 0.0)
    st = path_stations(path, rover, lambda a, b: b[0] <= 0.6 and b[1] > -0.1, 0.25, 1.0)
    straight = [s for s in st[1:] if s.rover[1] == pytest.approx(0.0) and s.rover[0] != 0.0]
    assert sorted(round(s.rover[0], 2) for s in straight) == [-1.0, -0.75, -0.5, -0.25, 0.25, 0.5]
    assert all(s.rover[2] == 0.0 and s.travel_m == pytest.approx(abs(s.rover[0])) for s in straight)
    # the path's stations were refused (the lambda): boxed in, so the straight moves are escapes,
    # and so is the turn in place to the path's other heading (its own heading is the path's)
    assert [s.rover for s in st[1:] if s not in straight] == [(0.0, 0.0, math.pi)]
    assert all(s.escape for s in st[1:])
    on_path = path_stations(path, (0.0, -0.45, 0.0), _ok, 0.25, 1.0)
    assert all(s.rover[1] == pytest.approx(-0.5) for s in on_path[1:])


def test_raster_first_station_moves_on_when_the_projection_is_refused() -> None:
    """Method 1's first row starts at the rover's projection on the path; if the geofence
    refuses that (issue 13 item 3: e.g. its footprint leaves the map), at the nearest path point
    on in the row's direction that it allows, not at the rover's own pose."""
    state = _straight_state(40.0)
    state = PlannerState(state.map, (0.0, 0.2, 0.0), state.joints, state.path,  # beside the path
                         lambda a, b: b[0] >= 0.3 - 1e-9, edge_xy=state.edge_xy)
    views = _run(RasterPlanner(False, 3, NbvConfig(), CAM, MAST), state, 3)
    assert views[0].rover[0] == pytest.approx(0.3, abs=1e-6) and views[0].rover[1] == pytest.approx(0.0)
    refused = PlannerState(state.map, state.rover, state.joints, state.path, lambda a, b: _close(a, b),
                           edge_xy=state.edge_xy)
    stay = _run(RasterPlanner(False, 3, NbvConfig(), CAM, MAST), refused, 1)
    assert stay[0].rover == state.rover  # nothing allowed: the view from where it stands


def test_with_no_edge_path_the_stations_are_the_edge_search_around_the_rover() -> None:
    """No edge path yet: stations every spacing along eight directions, each facing the way it
    was driven, each ray up to the first the geofence refuses (here: beyond x = 0.6)."""
    st = path_stations(np.zeros((0, 2)), (0.0, 0.0, 0.0), lambda a, b: b[0] <= 0.6, 0.25, 1.0)
    assert st[0].rover == (0.0, 0.0, 0.0)
    ahead = [s for s in st[1:] if abs(s.rover[1]) < 1e-9 and s.rover[0] > 0]
    assert [round(s.rover[0], 2) for s in ahead] == [0.25, 0.5]
    assert all(s.rover[0] <= 0.6 for s in st[1:])
    behind = [s for s in st[1:] if abs(s.rover[1]) < 1e-9 and s.rover[0] < 0]
    assert len(behind) == 4 and all(abs(abs(s.rover[2]) - math.pi) < 1e-9 for s in behind)
    assert all(math.isclose(s.travel_m, math.hypot(*s.rover[:2])) for s in st[1:])
    assert len({round(math.atan2(s.rover[1], s.rover[0]), 6) for s in st[1:]}) == 8


def _back_only(a: tuple, b: tuple) -> bool:
    """A stand-in geofence for a rover facing a close edge: no turn, no move toward the edge;
    only straight back (its heading kept)."""
    back = (b[0] - a[0]) * math.cos(a[2]) + (b[1] - a[1]) * math.sin(a[2])
    side = -(b[0] - a[0]) * math.sin(a[2]) + (b[1] - a[1]) * math.cos(a[2])
    return abs(math.remainder(b[2] - a[2], math.tau)) < 1e-9 and back < -0.05 and abs(side) < 1e-9


@pytest.mark.parametrize("method", ["3", "5"])
def test_a_rover_boxed_in_by_a_close_edge_backs_off(method: str) -> None:
    """Issue 30 item 1: the rover stands on the edge path facing the edge; the turn toward the
    path is refused, so no path station is reachable. The information planners take an escape
    move (here: straight back) instead of a view from where they stand; with no move allowed at
    all they stay and say why."""
    base = _synthetic_state(_back_only)
    state = dataclasses.replace(base, rover=(0.0, 0.0, -math.pi / 2))
    st = path_stations(state.path, state.rover, _back_only, 0.25, 1.0)
    assert len(st) > 1 and all(s.escape for s in st[1:])  # only escape moves: back
    planner = make_planner(method, 6, FAST, CAM, MAST)
    view = planner.next_view(state)
    assert view is not None and view.rover[1] > 0.2 and view.rover[2] == -math.pi / 2 and not view.note
    stuck = planner.next_view(dataclasses.replace(state, motion_ok=lambda a, b: False))
    assert stuck is not None and stuck.rover == state.rover and "no move the geofence allows" in stuck.note


def test_a_boxed_rover_may_turn_in_place_to_the_path() -> None:
    """A turn in place to the path's heading is an escape move when the geofence allows it (the
    drive along the path refused), either way along the path."""
    path = np.array([[-3.0, 0.0], [3.0, 0.0]])
    turns_only = lambda a, b: math.hypot(b[0] - a[0], b[1] - a[1]) < 1e-9  # noqa: E731
    st = path_stations(path, (0.0, 0.0, -math.pi / 2), turns_only, 0.25, 1.0)
    assert sorted(round(s.rover[2], 6) for s in st[1:]) == [0.0, round(math.pi, 6)]
    assert all(s.escape and s.rover[:2] == (0.0, 0.0) for s in st[1:])
    assert len(path_stations(path, (0.0, 0.0, 0.0), _ok, 0.25, 1.0)) > 1 and not any(
        s.escape for s in path_stations(path, (0.0, 0.0, 0.0), _ok, 0.25, 1.0))
