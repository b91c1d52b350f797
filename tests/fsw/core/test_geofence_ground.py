"""The geofence on unfamiliar ground (issue 13 item 3; docs/algorithm.md §2).

Requirements: a move over ground the map has not measured is refused, naming the wheel, and
allowed once the ground is mapped or stood on; the move is checked as the motion task drives
it (turn in place, drive, turn), so a turn that swings a corner over the edge is refused; the
edge's straight continuation stops at the rover's own footprint and at unknown ground; a
rover whose fitted edge runs through its wheels may back straight away, never closer; the
edge path exists for a short, hooked glimpse of an edge; the look view aims at the ground.
"""

from __future__ import annotations

import math

import numpy as np
from shapely.geometry import LineString, MultiLineString

from fsw.core.edge.edge import EdgeModel, edge_path
from fsw.core.edge.geofence import Geofence, GeofenceConfig, goto_legs
from fsw.core.edge.look import look_joints
from fsw.core.geometry import MapGrid, MapGridConfig, MastConfig, RoverConfig
from fsw.core.map.elevation_map import ElevationMap
from fsw.core.motion.motion_profile import MotionConfig

GRID = MapGrid.from_config(MapGridConfig(origin_x_m=-2.0, origin_y_m=-3.0, cell_m=0.03,
                                         nx=250, ny=200))


def edge_along_x(y: float = -1.0, x0: float = -1.5, x1: float = 5.0) -> EdgeModel:
    """An edge along +x at ``y``, the plateau (larger y) on its left."""
    line = LineString([(x0, y), (x1, y)])
    return EdgeModel("polygon", np.asarray(line.coords), MultiLineString([line]), None)


def mapped_box(x0: float, x1: float, y0: float, y1: float) -> np.ndarray:
    X, Y = GRID.centers()
    return ((x0 <= X) & (x1 >= X) & (y0 <= Y) & (y1 >= Y)).astype(np.int32)


def fence(n: np.ndarray | None, edge: EdgeModel, stand=(0.0, 0.0, 0.0), **kw) -> Geofence:
    gf = Geofence(GeofenceConfig(**kw), RoverConfig())
    if n is not None:
        gf.set_map(GRID, n)
    gf.set_edge(edge, stand)
    return gf


def test_unknown_ground_is_refused_and_mapped_ground_allowed():
    edge = edge_along_x(-1.0)
    only_near = mapped_box(-1.0, 1.0, -0.9, 1.0)  # mapped around the start only
    gf = fence(only_near, edge)
    v = gf.check((0.0, 0.0, 0.0), (2.0, 0.0, 0.0))
    assert not v.allowed and "unknown ground" in v.reason and "front" in v.reason
    assert len(gf.unknown_points((0.0, 0.0, 0.0), (2.0, 0.0, 0.0))) > 10
    # The edge check alone (what planners rate with) lets it through ...
    assert gf.check((0.0, 0.0, 0.0), (2.0, 0.0, 0.0), known_ground=False).allowed
    # ... and once the ground is mapped the move is allowed.
    gf.set_map(GRID, mapped_box(-1.0, 3.0, -0.9, 1.0))
    assert gf.check((0.0, 0.0, 0.0), (2.0, 0.0, 0.0)).allowed


def test_ground_stood_on_is_known_and_small_holes_are_filled():
    edge = edge_along_x(-1.0)
    n = mapped_box(-1.5, 3.0, -0.9, 1.0)
    n[:, 100:102] = 0  # a stereo drop-out 2 cells wide across the way (x = 1.0 .. 1.06)
    gf = fence(n, edge)
    assert gf.check((0.0, 0.0, 0.0), (2.0, 0.0, 0.0)).allowed  # closed by known_fill_m
    gf = fence(n, edge, known_fill_m=0.0)
    assert not gf.check((0.0, 0.0, 0.0), (2.0, 0.0, 0.0)).allowed
    # Nothing mapped at all: only the footprint stood on is known. Standing is fine; a turn
    # in place swings the wheels out of it, onto unknown ground.
    gf = fence(np.zeros(GRID.shape, np.int32), edge)
    assert gf.check((0.0, 0.0, 0.0), (0.0, 0.0, 0.0)).allowed
    assert not gf.check((0.0, 0.0, 0.0), (0.0, 0.0, 0.3)).allowed
    assert not gf.check((0.0, 0.0, 0.0), (0.5, 0.0, 0.0)).allowed


def test_goto_is_checked_as_the_motion_task_drives_it():
    legs = goto_legs((0.0, 0.0, 0.0), (0.0, 1.0, 0.0))
    assert math.isclose(legs[1][2], math.pi / 2) and legs[2][:2] == (0.0, 1.0)
    back = goto_legs((0.0, 0.0, 0.0), (-1.0, 0.1, 0.0))  # behind: back up, small turn
    assert abs(back[1][2]) < 0.2
    # The rover's right wheels 0.2 m from the edge: driving straight on is fine; a station up
    # and to the left needs a turn in place that swings the rear right corner over the edge.
    edge = edge_along_x(-0.56)
    n = np.ones(GRID.shape, np.int32)
    gf = fence(n, edge, margin_m=0.05)
    assert gf.check((0.0, 0.0, 0.0), (1.0, 0.0, 0.0)).allowed
    v = gf.check((0.0, 0.0, 0.0), (0.3, 0.8, 0.0))
    assert not v.allowed and "rear_right" in v.wheel


def test_fit_through_the_wheels_lets_the_rover_back_straight_away():
    """The fitted edge runs through the right wheels (a fit error: the rover stands on safe
    ground). Backing straight away from it is allowed, a move along it is not."""
    edge = edge_along_x(-0.3)
    n = np.ones(GRID.shape, np.int32)
    gf = fence(n, edge)
    stand = (0.0, 0.0, math.pi / 2)  # facing away from the edge
    gf.set_edge(edge, stand)
    assert gf.check(stand, (0.0, 0.8, math.pi / 2)).allowed
    assert not gf.check(stand, (0.0, -0.1, math.pi / 2)).allowed  # closer
    assert not gf.check((0.0, 0.0, 0.0), (1.0, 0.0, 0.0)).allowed  # along it


def test_extension_stops_at_the_footprint_and_unknown_ground():
    """A glimpsed edge whose end hooks toward the rover: its straight continuation would run
    through the rover; it stops short of the footprint, and at unknown ground."""
    line = LineString([(2.0, -0.3), (1.0, -0.55), (0.8, -0.5)])  # plateau left = up
    model = EdgeModel("polygon", np.asarray(line.coords), MultiLineString([line]), None)
    n = mapped_box(-2.0, 5.0, -3.0, 2.0)
    gf = fence(n, model)
    barrier = gf._barrier
    assert barrier is not None and not barrier.intersects(gf.footprint((0.0, 0.0, 0.0)))
    gf2 = fence(mapped_box(0.7, 5.0, -3.0, 2.0), model)  # unknown west of x = 0.7
    assert gf2._barrier is not None and gf2._barrier.bounds[0] >= 0.6  # 0.7 less known_fill_m


def test_edge_path_from_a_short_wiggly_glimpse():
    """The offset of a short edge that bends tighter than the setback collapses; the path is
    made by normal offsets, and continued past the glimpse like the geofence's edge."""
    x = np.linspace(0.7, 1.3, 25)
    y = -0.45 + 0.05 * np.sin((x - 0.7) * 12.0)
    line = LineString(np.column_stack([x, y]))
    model = EdgeModel("polygon", np.asarray(line.coords), MultiLineString([line]), None)
    path = edge_path(model, 0.75, 0.25, extend_m=1.0)
    assert len(path) >= 3
    assert (path[:, 1] > 0.1).all()  # on the plateau side, set back
    assert np.median(np.abs(np.cos(path[:, 2]))) > 0.8


def test_look_joints_aim_at_the_unknown_ground():
    mast = MastConfig()
    pan, tilt, lift = look_joints((0.0, 0.0, 0.0), np.array([[0.3, -1.0], [0.3, -1.2]]), mast)
    assert math.isclose(pan, -math.pi / 2, abs_tol=1e-6)  # mast base at x = 0.3: straight right
    assert tilt < math.radians(-40) and lift == mast.lift_max_m
    pan, tilt, _ = look_joints((0.0, 0.0, 0.0), np.array([[0.31, 0.0]]), mast)
    assert math.isclose(tilt, math.radians(mast.tilt_min_deg))  # right under the mast: clamped


def test_elevation_map_counts_drive_known_ground():
    m = ElevationMap(GRID)
    gf = Geofence(GeofenceConfig(), RoverConfig())
    gf.set_map(GRID, m.n)
    assert gf.known.ready and gf.known.unknown_cells(gf.footprint((1.0, 1.0, 0.0))) > 50


def test_extension_stops_in_any_piece_of_the_mapped_plateau():
    """The plateau fitted in two pieces (their contours are separate polygons): an edge piece's
    straight continuation stops where it enters either of them, not only the largest one."""
    from shapely.geometry import MultiPolygon, box

    line = LineString([(1.0, -1.0), (2.0, -1.3)])  # continues back toward (0, -0.7), up-left
    big = box(-1.5, 0.05, 2.5, 2.0)  # the larger piece, left of the rover
    beside = box(-1.0, -0.95, 2.5, -0.02)  # the piece beside the drop
    for poly, clipped in ((big, False), (MultiPolygon([big, beside]), True)):
        model = EdgeModel("polygon", np.asarray(line.coords), MultiLineString([line]), poly)
        b = model.barrier(1.0)
        x_min = min(g.bounds[0] for g in b.geoms)
        assert (x_min > 0.5) is clipped, (x_min, clipped)  # clipped ~0.67 (5 cm in), else ~0.05


def test_a_wheel_off_the_map_grid_is_refused_even_by_the_edge_only_check():
    """Ground off the map grid can never be known (no view maps it): a planner's station whose
    wheels would leave the grid is refused by the edge-only check too, naming the reason, so
    no look is spent on it; a station inside the grid passes that check."""
    n = mapped_box(-2.0, 5.5, -3.0, 3.0)  # the grid spans x -2 .. 5.5
    gf = fence(n, edge_along_x(-2.5), stand=(4.5, 0.0, 0.0))
    v = gf.check((4.5, 0.0, 0.0), (5.3, 0.0, 0.0), known_ground=False)
    assert not v.allowed and "leave the map" in v.reason
    assert gf.check((4.5, 0.0, 0.0), (4.9, 0.0, 0.0), known_ground=False).allowed
    assert gf.check((4.5, 0.0, 0.0), (4.9, 0.0, 0.0)).allowed  # mapped all the way


def test_a_turn_that_clips_the_grid_border_is_the_missions_to_refuse_not_the_planners():
    """A rover parked 0.5 m from the grid's border (lab and generated terrains start so): a
    turn in place swings its rear wheels off the grid. The planner's edge-only check still
    allows a station whose wheels REST on the grid (else no station is ever reachable from the
    start and the rover never moves); the mission's check refuses the turn (off the grid) and
    drives the straight part instead."""
    n = mapped_box(-0.5, 5.5, -3.0, 3.0)  # mapped (and, for the planner, reachable) from x = -0.5
    gf = fence(n, edge_along_x(-2.5), stand=(0.0, 0.0, 0.0))
    there = (0.3, 0.5, 0.0)  # needs a turn toward +y first: the rear wheels sweep x < -0.5
    assert gf.check((0.0, 0.0, 0.0), there, known_ground=False).allowed
    v = gf.check((0.0, 0.0, 0.0), there)
    assert not v.allowed and v.reason.startswith("rejected: wheel rear_") and "unknown ground" in v.reason
    assert gf.check((0.0, 0.0, 0.0), (0.6, 0.0, 0.0)).allowed  # straight ahead: no turn


def test_with_no_edge_fitted_the_rover_keeps_its_wheels_away_from_mapped_drop_cells():
    """The edge search (§2): no edge fitted (the views from the start did not reach the drop),
    so moves are judged against the drop cells the map does show: margin_m from every one of
    them, and on known ground as always. Without the drop map, or with the search turned off,
    nothing moves."""
    X, Y = GRID.centers()
    drop = (Y < -1.5) & (X > 0.5) & (X < 1.0)  # a glimpse of the pit floor, right of the rover
    gf = fence(mapped_box(-1.0, 3.0, -2.0, 1.0), EdgeModel("polygon", np.zeros((0, 2)), MultiLineString(), None))
    here = (0.0, 0.0, 0.0)
    assert not gf.check(here, (1.0, 0.0, 0.0)).allowed  # no drop map yet
    gf.set_drop(GRID, drop)
    ok = gf.check(here, (1.0, 0.0, 0.0))  # along it, 1.2 m away
    assert ok.allowed and "drop" in ok.reason
    for there in ((0.75, -0.9, -math.pi / 2), (0.75, -1.1, -math.pi / 2)):  # wheels within 0.15 m / over it
        v = gf.check(here, there, known_ground=False)
        assert not v.allowed and "drop" in v.reason
    assert not gf.check(here, (3.5, 0.0, 0.0)).allowed  # unknown ground beyond x = 3: refused
    off = fence(mapped_box(-1.0, 3.0, -2.0, 1.0), EdgeModel("polygon", np.zeros((0, 2)), MultiLineString(), None),
                explore_without_edge=False)
    off.set_drop(GRID, drop)
    assert not off.check(here, (1.0, 0.0, 0.0)).allowed


def test_a_long_drive_keeps_its_drift_away_from_unknown_ground():
    """Dead reckoning drifts as the rover drives (a heading error bends the path): the ground
    checks widen each swept wheel patch by drift_k sigmas of the drift grown to that sample.
    A 3 m drive along a 0.9 m wide mapped strip is refused, a 0.3 m one allowed, and without a
    drift model both are allowed (the footprint fits the strip)."""
    strip = mapped_box(-1.0, 4.0, -0.45, 0.45)
    gf = fence(strip, edge_along_x(-2.5))
    assert gf.check((0.0, 0.0, 0.0), (3.0, 0.0, 0.0)).allowed
    gf.set_drift(0.0, MotionConfig())
    long = gf.check((0.0, 0.0, 0.0), (3.0, 0.0, 0.0))
    assert not long.allowed and "unknown ground" in long.reason
    assert gf.check((0.0, 0.0, 0.0), (0.3, 0.0, 0.0)).allowed
    # a larger heading sigma at the start (no registered view since a long drive) widens sooner
    gf.set_drift(math.radians(10.0), MotionConfig())
    assert not gf.check((0.0, 0.0, 0.0), (1.0, 0.0, 0.0)).allowed
    off = fence(strip, edge_along_x(-2.5), drift_k=0.0)
    off.set_drift(math.radians(10.0), MotionConfig())  # drift_k = 0: no widening
    assert off.check((0.0, 0.0, 0.0), (3.0, 0.0, 0.0)).allowed


def test_the_wheels_keep_the_margin_from_the_maps_frontier_where_a_lip_may_hide():
    """cliff-team seeds 1 and 2: the face below the lip is hidden from the plateau, so no drop
    cell is mapped near it and no edge is fitted; the plateau is mapped to the lip (the last
    cell straddles it) and known ground reaches known_fill_m past that. A rover backing toward
    the lip must keep margin_m from the unmapped ground, not merely stay on known ground; one
    already closer may drive away, never closer."""
    no_edge = EdgeModel("polygon", np.zeros((0, 2)), MultiLineString(), None)
    gf = fence(mapped_box(-1.0, 3.0, -1.06, 1.0), no_edge, stand=(0.0, -0.3, math.pi / 2))
    gf.set_drop(GRID, np.zeros(GRID.shape, bool))  # the face hidden: no drop cell mapped
    here = (0.0, -0.3, math.pi / 2)  # facing +y, the lip 0.31 m behind its rear wheels
    v = gf.check(here, (0.0, -0.65, math.pi / 2))  # backing up: rear patches 0.04 m past the mapped cells
    assert not v.allowed and "rear" in v.reason and "unknown ground" in v.reason
    assert len(gf.unknown_points(here, (0.0, -0.65, math.pi / 2))) > 0  # the mission looks there first
    assert gf.check(here, (0.0, -0.45, math.pi / 2)).allowed  # 0.165 m from the first unmapped cell
    assert gf.check(here, (1.0, -0.3, math.pi / 2)).allowed  # along the frontier, well inside
    close = (0.0, -0.55, math.pi / 2)  # left (by a pose error) 0.065 m from it: may leave, never closer
    gf.set_edge(no_edge, close)
    assert gf.check(close, (0.0, -0.3, math.pi / 2)).allowed
    assert not gf.check(close, (0.0, -0.62, math.pi / 2)).allowed
    # the planner's edge-only check is unchanged (the mission's check is the one that refuses)
    assert gf.check(here, (0.0, -0.65, math.pi / 2), known_ground=False).allowed
    # an edge fitted elsewhere (cliff-team seed 2, step 4: fitted where the face shows, its end
    # short of the rover) does not vouch for the unmapped ground behind the rover either
    fitted = fence(mapped_box(-1.0, 3.0, -1.06, 1.0), edge_along_x(-2.5, 2.0, 5.0), stand=here)
    v = fitted.check(here, (0.0, -0.65, math.pi / 2))
    assert not v.allowed and "rear" in v.reason and "unknown ground" in v.reason
    assert fitted.check(here, (0.0, -0.45, math.pi / 2)).allowed


def test_the_ground_stood_on_is_one_list_for_known_and_mapped_ground():
    """A resumed mission's footprints (``StoodOn.replace``) are known ground and mapped ground alike,
    at once: a move across the unmapped strip they cover is allowed, none of it stays within the margin."""
    n = mapped_box(-1.5, 3.0, -0.9, 1.0)
    n[:, 100:110] = 0  # an unmapped strip 0.3 m wide across the way (x = 1.0 .. 1.3)
    gf = fence(n, edge_along_x(-1.0))
    assert not gf.check((0.0, 0.0, 0.0), (2.0, 0.0, 0.0)).allowed
    strip = [gf.footprint((x, y, 0.0)) for x in (0.9, 1.2, 1.5) for y in (-0.3, 0.0, 0.3)]
    gf.stood.replace(strip)  # (the footprint where it stands, from set_edge, is replaced too)
    centre = np.array([[1.15, 0.0]])
    assert gf.known.known_xy(centre).all() and gf.mapped.known_xy(centre).all()
    assert gf.check((0.0, 0.0, 0.0), (2.0, 0.0, 0.0)).allowed


def test_the_side_of_the_edge_follows_the_known_ground_its_continuation_stops_at():
    """The edge's continuation stops at unknown ground, so a point past the end of the edge is
    judged against the continuation as the known ground is now: a new map or a footprint stood
    on lengthens it. (The geofence keeps the barrier's segments between checks while the known
    ground is unchanged, and builds them again once it has changed.)"""
    edge = edge_along_x(-1.0, 0.0, 2.0)
    gf = fence(mapped_box(-0.3, 2.5, -2.0, 1.0), edge, stand=(1.0, 0.0, 0.0))
    west = np.array([[-0.8, -1.1], [-0.5, -1.05]])  # west of the fit, on the drop's side of its line
    before = gf._edge_side(west)
    assert (before > 0).all()  # past the continuation's end (unknown beyond x = -0.36): the fit says nothing
    gf.set_map(GRID, mapped_box(-2.0, 2.5, -2.0, 1.0))
    after = gf._edge_side(west)
    assert (after < 0).all()  # the continuation now runs on to x = -1: beyond it
    np.testing.assert_array_equal(after, gf._edge.signed_distance(west, gf.cfg.extend_m))

    gf = fence(mapped_box(-0.3, 2.5, -2.0, 1.0), edge, stand=(1.0, 0.0, 0.0))
    assert (gf._edge_side(west) == before).all()
    gf.known.stood_on(gf.footprint((-0.7, -0.8, 0.0)))  # the ground west of the fit stood on
    stood = gf._edge_side(west)
    assert (stood < 0).any()
    np.testing.assert_array_equal(stood, gf._edge.signed_distance(west, gf.cfg.extend_m))
