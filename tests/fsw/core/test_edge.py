"""Cliff edge (docs/algorithm.md §2): points, polygon and line fits, path, and the geofence."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import shapely
from shapely.geometry import LineString, MultiLineString, Polygon
from shapely.geometry.polygon import orient

from fsw.core.edge.edge import (
    EdgeConfig,
    EdgeModel,
    _runs,
    edge_cells,
    edge_path,
    fit_line,
    fit_polygon,
)
from fsw.core.edge.edge_ring import densify_ring
from fsw.core.edge.geofence import Geofence, GeofenceConfig
from fsw.core.geometry import MapGrid, MapGridConfig, RoverConfig
from fsw.core.map.elevation_map import ElevationMap

GRID = MapGrid.from_config(MapGridConfig())


def true_edge_y(x: np.ndarray) -> np.ndarray:
    """A wavy edge with a bay (notch into the plateau) around x = 3."""
    return -0.8 + 0.1 * np.sin(2.0 * x) + 0.5 * np.exp(-(((x - 3.0) / 0.35) ** 4))


def synthetic_map(shadow_m: float = 0.3, x_max: float = 5.0) -> ElevationMap:
    """Plateau z=0 above the edge, pit z=-0.4 below it, an occluded band under the lip."""
    X, Y = GRID.centers()
    ey = true_edge_y(X)
    m = ElevationMap(GRID)
    known = ((ey <= Y) | (ey - shadow_m > Y)) & (x_max > X) & (Y < 1.2)
    m.z[known] = np.where(ey <= Y, 0.0, -0.4)[known]
    m.var[known] = 1e-4
    m.n[known] = 1
    return m


TRUTH = np.column_stack([np.linspace(-0.5, 7.0, 2000), true_edge_y(np.linspace(-0.5, 7.0, 2000))])


def test_polygon_fit_follows_a_non_convex_edge() -> None:
    """Issue 4, item 4: polygon (Methods 4/5) within a cell of a wavy edge with a bay; the
    straight segment (Method 3) is far worse; the map frontier is not taken as an edge."""
    m = synthetic_map()
    cfg = EdgeConfig()
    cells = edge_cells(m, 0.0, (1.0, 0.5), cfg)
    poly = fit_polygon(m, cells, cfg)
    line = fit_line(cells, (0.5, 0.0))
    d_poly = poly.mean_distance_to(TRUTH, GRID.cell)
    d_line = line.mean_distance_to(TRUTH, GRID.cell)
    assert d_poly <= 1.0 * GRID.cell
    assert d_line > 3 * d_poly
    # no edge points on the map frontier (x = 5 boundary, y = 1.2 boundary)
    assert cells.points_xy[:, 0].max() < 5.0 and cells.points_xy[:, 1].max() < -0.2
    assert poly.safe_polygon is not None and poly.safe_polygon.contains(
        __import__("shapely").geometry.Point(1.0, 0.0))


def test_drop_seen_across_a_long_occlusion_gap() -> None:
    """§2: the ground under the drop is occluded; the drop is found within search_m."""
    m = synthetic_map(shadow_m=0.45)
    cells = edge_cells(m, 0.0, (1.0, 0.5), EdgeConfig(search_m=0.6))
    assert len(cells.points_xy) > 100
    none = edge_cells(m, 0.0, (1.0, 0.5), EdgeConfig(search_m=0.3))
    # too short a search: no evidence of a drop, except where the bay's walls make the
    # horizontal gap shorter than the vertical shadow band
    assert len(none.points_xy) < 0.2 * len(cells.points_xy)


def test_hole_in_plateau_is_not_an_edge() -> None:
    """An unmapped hole inside the plateau (no stereo match) is not a cliff edge."""
    m = synthetic_map()
    X, Y = GRID.centers()
    hole = (np.hypot(X - 1.5, Y - 0.2) < 0.2)
    m.z[hole], m.var[hole], m.n[hole] = np.nan, np.inf, 0
    cells = edge_cells(m, 0.0, (1.0, 0.5), EdgeConfig())
    d = np.hypot(cells.points_xy[:, 0] - 1.5, cells.points_xy[:, 1] - 0.2)
    assert (d > 0.3).all()


def test_empty_map_gives_empty_edge() -> None:
    m = ElevationMap(GRID)
    cfg = EdgeConfig()
    cells = edge_cells(m, 0.0, (1.0, 0.5), cfg)
    assert fit_polygon(m, cells, cfg).empty and fit_line(cells, (0, 0)).empty
    assert edge_path(fit_polygon(m, cells, cfg), 0.7, 0.25).shape == (0, 3)


def test_path_is_set_back_on_the_safe_side() -> None:
    """§2: candidate positions follow the edge, setback_m into the plateau."""
    m = synthetic_map()
    cfg = EdgeConfig()
    poly = fit_polygon(m, edge_cells(m, 0.0, (1.0, 0.5), cfg), cfg)
    path = edge_path(poly, 0.75, 0.25)
    assert len(path) > 10
    import shapely
    d = shapely.distance(shapely.points(path[:, :2]), poly.lines)
    assert (d >= 0.74).all()
    assert (path[:, 1] > true_edge_y(path[:, 0])).all()  # plateau side
    assert np.median(np.abs(np.cos(path[:, 2]))) > 0.8  # heading along the edge (+-x)


@pytest.fixture(scope="module")
def fence() -> Geofence:
    m = synthetic_map()
    cfg = EdgeConfig()
    gf = Geofence(GeofenceConfig(margin_m=0.15), RoverConfig())
    gf.set_edge(fit_polygon(m, edge_cells(m, 0.0, (1.0, 0.5), cfg), cfg))
    return gf


def test_geofence_allows_motion_along_the_plateau(fence: Geofence) -> None:
    """Issue 4, item 4: safe moves are allowed, with the clearance in the reason."""
    v = fence.check((0.5, 0.3, 0.0), (1.5, 0.3, 0.0))
    assert v.allowed and "clearance" in v.reason and v.clearance_m > 0.15


def test_geofence_rejects_crossing_and_margin(fence: Geofence) -> None:
    """A command that takes a wheel across the edge, or inside the margin, is rejected."""
    v = fence.check((1.0, 0.3, -math.pi / 2), (1.0, -1.2, -math.pi / 2))
    assert not v.allowed and "crosses the edge" in v.reason and v.wheel
    # end pose with the front wheels 0.1 m from the lip: inside the 0.15 m margin
    y_end = float(true_edge_y(np.array([1.0]))[0]) + 0.35 + 0.05 + 0.1
    v = fence.check((1.0, 0.3, -math.pi / 2), (1.0, y_end, -math.pi / 2))
    assert not v.allowed and "within" in v.reason and 0.0 < v.clearance_m < 0.15


def test_geofence_checks_the_swept_footprint_not_just_end_poses(fence: Geofence) -> None:
    """Both end poses are safe but the straight drive cuts across the bay at x ~ 3."""
    a, b = (1.8, -0.15, 0.0), (4.2, -0.15, 0.0)
    assert fence.check(a, a).allowed and fence.check(b, b).allowed
    v = fence.check(a, b)
    assert not v.allowed


def test_geofence_turn_in_place_sweeps_the_wheels() -> None:
    """A turn in place near a straight edge: the wheel arcs are checked at every sample."""
    m = synthetic_map()
    cells = edge_cells(m, 0.0, (1.0, 0.5), EdgeConfig())
    gf = Geofence(GeofenceConfig(margin_m=0.05), RoverConfig())
    gf.set_edge(fit_line(cells, (0.5, 0.5)))
    y0 = float(np.mean(cells.points_xy[:, 1])) + 0.55
    # heading along the edge the wheels clear it; sideways the diagonal would not
    assert gf.check((1.0, y0, 0.0), (1.0, y0, 0.0)).allowed
    assert not gf.check((1.0, y0, 0.0), (1.0, y0, math.pi)).allowed


def test_geofence_lets_a_rover_inside_the_margin_back_away_but_never_closer(fence: Geofence) -> None:
    """A new edge fit can leave the standing rover inside the margin: it may move out of the
    margin without coming closer on the way (recovering); a move closer, or one that stays
    inside, is still refused, and with recovery off every move from there is refused."""
    y_in = float(true_edge_y(np.array([1.0]))[0]) + 0.35 + 0.05 + 0.1  # front wheels ~0.1 m off the lip
    here = (1.0, y_in, -math.pi / 2)
    assert not fence.check((1.0, 0.3, -math.pi / 2), here).allowed  # it may not drive in there
    away = fence.check(here, (1.0, y_in + 0.3, -math.pi / 2))
    assert away.allowed and "recovering" in away.reason and 0.0 < away.clearance_m < 0.15
    closer = fence.check(here, (1.0, y_in - 0.05, -math.pi / 2))
    assert not closer.allowed and "within" in closer.reason
    inside = fence.check(here, (1.0, y_in + 0.02, -math.pi / 2))  # away, but still inside the margin
    assert not inside.allowed and "within" in inside.reason
    strict = Geofence(GeofenceConfig(margin_m=0.15, recover_inside_margin=False), RoverConfig())
    strict.set_edge(fence._edge)
    assert not strict.check(here, (1.0, y_in + 0.3, -math.pi / 2)).allowed


def test_geofence_refuses_bad_input_and_unknown_edge() -> None:
    gf = Geofence(GeofenceConfig(), RoverConfig())
    v = gf.check((0, 0, 0), (1, 0, 0))
    assert not v.allowed and "no cliff edge" in v.reason
    v = gf.check((0, float("nan"), 0), (1, 0, 0))
    assert not v.allowed and "finite" in v.reason
    v = gf.check((0, 0), (1, 0, 0))  # type: ignore[arg-type]
    assert not v.allowed
    assert gf.rejections == 3
    assert Geofence(GeofenceConfig(allow_without_edge=True), RoverConfig()).check(
        (0, 0, 0), (1, 0, 0)).allowed


def test_signed_distance_classifies_bay_and_plateau(fence: Geofence) -> None:
    """§2: the side is that of the nearest edge point, so a narrow bay does not spill over."""
    m = synthetic_map()
    cfg = EdgeConfig()
    poly = fit_polygon(m, edge_cells(m, 0.0, (1.0, 0.5), cfg), cfg)
    pts = np.array([[3.0, -0.6],   # inside the bay (pit)
                    [3.6, -0.5],   # plateau just east of the bay
                    [1.0, 0.5],    # plateau
                    [1.0, -2.0]])  # pit
    sd = poly.signed_distance(pts)
    assert sd[0] < 0 and sd[1] > 0 and sd[2] > 0 and sd[3] < 0
    v = fence.check((1.0, -2.5, 0.0), (1.5, -2.5, 0.0))  # wholly in the pit, far from the lip
    assert not v.allowed and "beyond the edge" in v.reason and v.clearance_m < 0


CLIFF_STEP0 = Path(__file__).parent / "data" / "cliff_step0_edge.npz"


def _cliff_step0() -> tuple[EdgeModel, np.ndarray, np.ndarray]:
    """The cliff scenario's edge after the step-0 panorama (seed 0): the safe polygon, the
    edge points, and the two edge runs the fit then gave (split at a small spike of the
    polygon at x = 1.25; the second run starts with a hook back west)."""
    d = np.load(CLIFF_STEP0)
    model = EdgeModel("polygon", d["points_xy"],
                      MultiLineString([LineString(d["run0"]), LineString(d["run1"])]),
                      Polygon(d["polygon_xy"]))
    return model, d["points_xy"], d["polygon_xy"]


def test_cliff_step0_edge_is_one_run() -> None:
    """Issue: the polygon's edge runs are not split by a spike a few cm past ``match_m``."""
    cfg = EdgeConfig()
    _, pts, ring = _cliff_step0()
    poly = orient(Polygon(ring), 1.0)
    ring = densify_ring(np.asarray(poly.exterior.coords), GRID.cell)
    tree = shapely.STRtree(shapely.points(pts))
    near = tree.query(shapely.points(ring), predicate="dwithin", distance=cfg.match_m)
    flag = np.zeros(ring.shape[0], bool)
    flag[np.unique(near[0])] = True
    runs = _runs(ring, flag, cfg)
    assert len(runs) == 1 and runs[0].length > 3.0


def test_cliff_step0_barrier_does_not_cut_the_plateau() -> None:
    """Issue: on the cliff after step 0 the geofence refused moves well back from the true
    edge ("wheel rear_right is beyond the edge"): the straight continuation of the hooked
    start of an edge run swung back across the mapped plateau. An extension stops where it
    enters the safe polygon; the pit and the unmapped continuations stay refused."""
    model, _, _ = _cliff_step0()
    fence = Geofence(GeofenceConfig(), RoverConfig())
    fence.set_edge(model)
    for b in [(1.14, -0.20, -0.17), (-0.26, -0.27, 0.10), (0.02, -0.23, 0.04)]:
        assert fence.check((0.0, 0.0, 0.0), b).allowed, b
    assert model.signed_distance(np.array([[0.3, -0.5], [-0.3, -0.35]]), 1.0).min() > 0.3
    # still refused: into the pit, past the edge's ends along the drop, within the margin
    for b in [(0.5, -1.4, 0.0), (-1.2, -1.2, 0.0), (2.9, -1.2, 0.0), (0.5, -0.55, 0.0)]:
        assert not fence.check((0.0, -0.2, 0.0), b).allowed, b


def sloped_map(slope_deg: float) -> ElevationMap:
    """The wavy edge of :func:`synthetic_map` on a plateau that climbs along +x at
    ``slope_deg`` (the pit 0.4 m below the plateau, both following the slope)."""
    m = synthetic_map()
    X, _ = GRID.centers()
    m.z[m.mapped] += (math.tan(math.radians(slope_deg)) * X)[m.mapped]
    return m


@pytest.mark.parametrize("drift_m", [0.0, 0.04, -0.04])
def test_edge_on_a_slope_seen_from_a_rover_that_climbed(drift_m: float) -> None:
    """Issue 13's edge-violation defect: on an 8 deg plateau the rover 3 m from the start
    stands 0.42 m above the start's ground. The edge must be found along its whole length
    from there, with the ground height the pose chain gives (a few cm of drift absorbed by the
    plane fit). Taking the start's height instead loses it: the plateau becomes a strip
    across the slope, and the geofence then knows no edge beside the rover."""
    m, cfg = sloped_map(8.0), EdgeConfig()
    seed = (3.0, 0.0)
    ground = math.tan(math.radians(8.0)) * seed[0]
    cells = edge_cells(m, ground + drift_m, seed, cfg)
    poly = fit_polygon(m, cells, cfg)
    xs = cells.points_xy[:, 0]
    assert xs.min() < 0.0 and xs.max() > 4.5  # the whole edge the map saw (x = -0.5..5)
    assert poly.mean_distance_to(TRUTH, GRID.cell) < 1.5 * GRID.cell
    stale = edge_cells(m, 0.0, seed, cfg)  # the defect: the start's height, 0.42 m off
    assert stale.points_xy.shape[0] < 0.2 * cells.points_xy.shape[0]


def test_edge_on_rolling_ground_is_found_along_its_whole_length() -> None:
    """Rolling relief of +-5 cm over a metre leaves one plane's 3 cm band in patches: the
    plateau breaks up and the edge beside the broken parts goes unseen. The ground surface
    (``surface_scale_m``) follows the relief, so the plateau stays one piece and the whole
    edge is found; the drop itself is never taken for plateau."""
    m = synthetic_map()
    X, Y = GRID.centers()
    m.z[m.mapped] += (0.05 * np.sin(2.0 * np.pi * X / 1.2) * np.cos(2.0 * np.pi * Y / 1.5))[m.mapped]
    rolling = edge_cells(m, 0.0, (1.0, 0.5), EdgeConfig())
    plane = edge_cells(m, 0.0, (1.0, 0.5), EdgeConfig(surface_scale_m=0.0))
    plateau = m.mapped & (true_edge_y(X) <= Y)
    assert rolling.safe[plateau].mean() > 0.95 and plane.safe[plateau].mean() < 0.8
    assert not (rolling.safe & (true_edge_y(X) - 0.05 > Y)).any()
    fits = [fit_polygon(m, c, EdgeConfig()) for c in (rolling, plane)]
    length = [sum(g.length for g in f.lines.geoms) for f in fits]
    assert length[0] > 5.0 > 3.0 > length[1]  # the whole edge (x = -0.5..5 with its bay) / pieces of it
    assert fits[0].mean_distance_to(TRUTH, GRID.cell) < 1.5 * GRID.cell
    assert rolling.drop is not None and rolling.drop[m.mapped & (true_edge_y(X) - 0.35 > Y)].all()
