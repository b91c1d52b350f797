"""The Cliff-bot's task planner (docs/algorithm.md §8): usable ground, tether limits, reasons."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import ndimage

from fsw.core.geometry import MapGrid
from fsw.core.team.climber_ground import ClimberConfig, disc, footprint_known, ground_layers
from fsw.core.team.face_planner import (
    OFF_THE_WAY,
    USABLE,
    Margins,
    _tether_verdict,
    node_reasons,
    plan_targets,
    raw_hazard_distance,
    way_reason,
)
from fsw.core.team.tether import TetherConfig, anchor_points, tether_state
from hil_sim.lab.bench.bench_planner import footprint_known_whole_map

SLOPE = math.radians(70.0)
ANCHORS_XY = np.array([[-1.5, 1.5], [1.5, 1.5]])
START = np.array([0.0, 0.6])


def cliff(drop_m: float = 2.5) -> tuple[np.ndarray, MapGrid]:
    grid = MapGrid(-3.0, -2.0, 0.03, 200, 150)
    _, y = grid.centers()
    z = np.where(y > 0, 0.0, np.maximum(math.tan(SLOPE) * y, -drop_m))
    return z.astype(np.float32), grid


def boulder(z: np.ndarray, grid: MapGrid, x: float, y: float, r: float, h: float) -> None:
    gx, gy = grid.centers()
    inside = np.hypot(gx - x, gy - y) < r
    z[inside] += h


def plan(z: np.ndarray, grid: MapGrid, targets: list[tuple[float, float]], tcfg: TetherConfig | None = None):
    tcfg = tcfg or TetherConfig()
    anchors = anchor_points(z, grid, ANCHORS_XY, tcfg)
    return plan_targets(z, grid, anchors, START, np.array(targets), tcfg, ClimberConfig())


@pytest.mark.slow
def test_reaches_a_face_target_and_never_leaves_usable_ground() -> None:
    z, grid = cliff()
    boulder(z, grid, -0.3, -0.5, 0.15, 0.35 / math.cos(SLOPE))  # 0.35 m off the face: over a wheel
    p = plan(z, grid, [(0.3, -0.6), (-0.3, -0.5)])
    assert p.start_reason == ""
    assert p.reasons[0] == "" and p.paths[0] is not None
    assert p.reasons[1] == "hazard" and p.paths[1] is None
    g = ground_layers(z, grid, ClimberConfig(), anchors=anchor_points(z, grid, ANCHORS_XY, TetherConfig()))
    iy, ix, inside = grid.cell_index(p.paths[0][:, 0], p.paths[0][:, 1])
    assert inside.all() and not g.hazard[iy, ix].any() and g.known[iy, ix].all()
    # The path goes down the face: it ends well below the lip.
    assert z[iy[-1], ix[-1]] < -1.0
    # Its length is at least the straight 3-D distance from start to target.
    straight = math.dist((*START, 0.0), (0.3, -0.6, float(z[iy[-1], ix[-1]])))
    assert p.lengths_m[0] >= straight - 0.1


@pytest.mark.slow
def test_reasons_for_unreachable_targets() -> None:
    z, grid = cliff()
    gx, gy = grid.centers()
    z[(gx > 1.5) & (gy < -0.2)] = np.nan  # a corner the map does not know
    short = TetherConfig(spool_m=3.2)
    p = plan(z, grid, [(2.2, -0.8), (0.0, -1.5), (9.0, 9.0)], short)
    assert p.reasons[0] == "unknown ground"
    assert p.reasons[1] in ("out of tether reach", "slack", "over-tension")
    assert p.reasons[2] == "off the map"


@pytest.mark.slow
def test_a_rock_band_across_the_face_blocks_the_way_down() -> None:
    z, grid = cliff()
    gx, gy = grid.centers()
    band = (gy < -0.35) & (gy > -0.5)
    z[band] += 0.3 / math.cos(SLOPE)  # a continuous band of rock standing 0.3 m off the face
    p = plan(z, grid, [(0.0, -1.0)])
    assert p.paths[0] is None and p.reasons[0] in ("no safe path", "hazard", "tether over a rock")


@pytest.mark.slow
def test_node_verdicts_are_known_reasons() -> None:
    z, grid = cliff()
    rows, cols, reasons, _ = node_reasons(z, grid, anchor_points(z, grid, ANCHORS_XY, TetherConfig()),
                                          TetherConfig(), ClimberConfig(node_m=0.15))
    assert len(reasons) == len(rows) * len(cols)
    assert reasons.count(USABLE) > 0.2 * len(reasons)


def _flat_with_a_rock() -> tuple[np.ndarray, MapGrid, np.ndarray]:
    grid = MapGrid(-1.5, -1.5, 0.05, 60, 60)
    z = np.zeros((60, 60), np.float32)
    boulder(z, grid, 0.0, -0.6, 0.15, 0.3)
    return z, grid, anchor_points(z, grid, np.array([[-1.2, 1.3], [1.2, 1.3]]), TetherConfig())


def test_soft_margins_keep_clear_without_changing_what_is_reachable() -> None:
    z, grid, anchors = _flat_with_a_rock()
    start, target = np.array([-0.9, -0.6]), np.array([[0.9, -0.6]])  # the rock in between
    hard = plan_targets(z, grid, anchors, start, target, TetherConfig(), ClimberConfig())
    soft = plan_targets(z, grid, anchors, start, target, TetherConfig(), ClimberConfig(), Margins(0.3))
    assert hard.reasons == soft.reasons == ("",)
    g = ground_layers(z, grid, ClimberConfig(), anchors=anchors)
    from scipy import ndimage

    clear = ndimage.distance_transform_edt(~g.hazard) * grid.cell

    def closest(path: np.ndarray) -> float:
        iy, ix, _ = grid.cell_index(path[:, 0], path[:, 1])
        return float(clear[iy, ix].min())

    assert hard.paths[0] is not None and soft.paths[0] is not None
    assert closest(soft.paths[0]) >= closest(hard.paths[0]) + 0.1  # it keeps away from the rock
    assert hard.lengths_m[0] < soft.lengths_m[0] < 1.5 * hard.lengths_m[0]  # lengths are lengths, not costs
    seg = np.diff(np.column_stack([soft.paths[0], np.zeros(len(soft.paths[0]))]), axis=0)
    assert math.isclose(soft.lengths_m[0], float(np.linalg.norm(seg, axis=1).sum()), rel_tol=1e-6)


def test_a_start_on_a_hazard_is_left_only_when_the_cliffbot_stands_there() -> None:
    z, grid, anchors = _flat_with_a_rock()
    start, target = np.array([0.0, -0.18]), np.array([[0.0, 0.5]])  # at the edge of the rock's hazard
    strict = plan_targets(z, grid, anchors, start, target, TetherConfig(), ClimberConfig())
    assert strict.start_reason == "hazard" and strict.reasons == ("start: hazard",)
    out = plan_targets(z, grid, anchors, start, target, TetherConfig(), ClimberConfig(), start_usable=True)
    assert out.start_reason == "" and out.reasons == ("",) and out.paths[0] is not None


def test_the_way_out_of_a_start_in_a_hazard_gets_no_nearer_the_rock() -> None:
    """A newer map may put a rock beside where the Cliff-bot stands: its node, and the nodes round
    it, are then hazards. Standing there (``start_usable``) it plans its way out through hazard
    nodes no nearer a rock than its own (before: ``no safe path``, stranded), and a way judged as
    leaving (``way_reason(leaving=True)``) may not go nearer the rock."""
    z, grid, anchors = _flat_with_a_rock()  # a rock at (0, -0.6), 0.15 m round
    start, target = np.array([0.0, -0.3]), np.array([[0.0, 0.5]])
    c, t = ClimberConfig(), TetherConfig()
    g = ground_layers(z, grid, c, anchors=anchors)
    iy, ix, _ = grid.cell_index(start[:1], start[1:])
    assert g.hazard[iy[0], ix[0]]
    assert plan_targets(z, grid, anchors, start, target, t, c).reasons == ("start: hazard",)
    out = plan_targets(z, grid, anchors, start, target, t, c, start_usable=True)
    assert out.reasons == ("",) and out.paths[0] is not None
    d0 = raw_hazard_distance(grid, g, c, out.paths[0][0])
    assert all(raw_hazard_distance(grid, g, c, p) >= d0 - 1e-9 for p in out.paths[0])
    away, toward = np.array([0.0, -0.24]), np.array([0.0, -0.36])
    assert way_reason(z, grid, anchors, start, away, t, c, g) == "hazard"  # not leaving: judged as any way
    assert way_reason(z, grid, anchors, start, away, t, c, g, leaving=True) == ""
    assert way_reason(z, grid, anchors, start, toward, t, c, g, leaving=True) == "hazard"
    # a target beyond the rock: the way round it crosses the hazard no nearer the rock than the start
    beyond = plan_targets(z, grid, anchors, start, np.array([[0.6, -1.0]]), t, c, start_usable=True)
    assert beyond.reasons == ("",) and beyond.paths[0] is not None
    py, px, _ = grid.cell_index(beyond.paths[0][:, 0], beyond.paths[0][:, 1])
    assert all(raw_hazard_distance(grid, g, c, p) >= d0 - 1e-9 for p in beyond.paths[0][g.hazard[py, px]])


def _face_with_a_ledge() -> tuple[np.ndarray, MapGrid]:
    """A 75 deg face, a 0.5 m ledge 1.5 m below the lip, the face again below it."""
    grid = MapGrid(-1.8, -1.6, 0.03, 120, 110)
    _, y = grid.centers()
    s = math.tan(math.radians(75.0))
    top, foot = -1.5 / s, -1.5 / s - 0.5
    z = np.where(y > 0, 0.0, np.where(y > top, s * y, np.where(y > foot, -1.5, -1.5 + s * (y - foot))))
    return z.astype(np.float32), grid


@pytest.mark.slow
def test_the_way_between_nodes_is_judged_where_the_statics_put_the_body() -> None:
    """On the ledge the tether lengths first shrink outwards (the tethers leave the face's foot):
    moving them straight from one ledge node's lengths to the next's holds the body on the face
    above, not on the ledge, though both nodes are usable; down the face the way holds."""
    z, grid = _face_with_a_ledge()
    t, c = TetherConfig(), ClimberConfig()
    anchors = anchor_points(z, grid, ANCHORS_XY, t)
    g = ground_layers(z, grid, c)
    on_face, lower, at_foot, mid = (np.array([0.2, y]) for y in (-0.19, -0.28, -0.43, -0.64))
    for p in (on_face, lower, at_foot, mid):
        assert _tether_verdict(tether_state(z, grid, anchors, p, t, c.footprint_m), grid, t, c, g) == USABLE
    assert way_reason(z, grid, anchors, on_face, lower, t, c, g) == ""
    assert way_reason(z, grid, anchors, at_foot, mid, t, c, g) == OFF_THE_WAY
    assert way_reason(z, grid, anchors, mid, at_foot, t, c, g) == OFF_THE_WAY


def test_the_footprint_is_laid_in_the_grounds_plane() -> None:
    """On a 77 deg face a body 0.6 m long, heading down the dip, spans 0.6 cos 77 = 0.14 m of the
    map along the dip: a band of face 0.4 m wide on the map (1.8 m along the slope) holds such
    nodes, which the level footprint (0.6 m long on the map) never finds; across the dip it keeps
    its full half width, and flat ground keeps the level footprint."""
    g = MapGrid(0.0, 0.0, 0.08, 40, 40)
    x, y = g.centers()
    face = np.tan(np.radians(77.0)) * y
    anchors = np.array([[1.1, 6.0, 30.0], [2.1, 6.0, 30.0]])  # above the face: it heads down the dip
    c = ClimberConfig()
    band = np.where(np.abs(y - 1.6) <= 0.2, face, np.nan)
    got = footprint_known(band, g, c, anchors)
    level = ndimage.binary_erosion(np.isfinite(band), structure=np.ones((9, 1), bool), border_value=0)
    assert got.any() and not level.any()
    assert not (got & (np.abs(y - 1.6) > 0.125)).any()  # along the dip: within the band less the footprint
    assert not (got & ((x < c.body_half_width_m) | (x > 3.2 - c.body_half_width_m))).any()  # across: its half width
    # the same band on flat ground: nothing known; a flat strip within a footprint: the level one there
    flat = np.where(np.isfinite(band), 0.0, np.nan)
    assert not footprint_known(flat, g, c, anchors).any()
    ledge = np.where(np.isfinite(band) & (y > 1.7), 1.64 * np.tan(np.radians(77.0)), band)  # the band's top flat
    assert got.any() and not footprint_known(ledge, g, c, anchors).any()


def test_the_footprint_is_the_wheels_outline_at_the_heading_held() -> None:
    """The footprint is the body's box at the heading it holds (away from the anchors), not the
    disc round it: a strip of unknown ground 0.28 m beside the body's middle, where no camera
    sees, leaves a node a step ahead or behind along the heading known (the disc of the body's
    half length would hold the strip), and one a step across it not."""
    g = MapGrid(-1.5, -1.5, 0.03, 100, 100)
    x, y = g.centers()
    anchors = np.array([[-1.0, 1.5, 0.5], [1.0, 1.5, 0.5]])  # it heads down -y
    z = np.where((np.abs(x) >= 0.28) & (np.abs(x) <= 0.44) & (np.abs(y) < 0.6), np.nan, 0.0)
    known = footprint_known(z, g, ClimberConfig(), anchors)
    at = {p: bool(known[g.cell_index(np.array([p[0]]), np.array([p[1]]))[:2]][0])
          for p in ((0.0, 0.0), (0.0, -0.12), (0.0, 0.12), (0.1, 0.0))}
    assert at[(0.0, 0.0)] and at[(0.0, -0.12)] and at[(0.0, 0.12)] and not at[(0.1, 0.0)]
    disc_known = ndimage.binary_erosion(np.isfinite(z), structure=disc(10), border_value=0)
    assert not disc_known[g.cell_index(np.array([0.0]), np.array([-0.12]))[:2]][0]


@pytest.mark.parametrize("seed", range(4))
def test_footprint_known_gathers_what_whole_map_filters_give(seed: int) -> None:
    """footprint_known judges each cell with its own footprint only: the same cells as each
    footprint's minimum filter and erosion over the whole map (``safer-hil bench planner``'s
    reference), unknown cells and the map's borders included (rough random ground: every
    slope level, dip bin and heading bin)."""
    rng = np.random.default_rng(seed)
    g = MapGrid(0.0, 0.0, 0.03, int(rng.integers(30, 70)), int(rng.integers(30, 70)))
    z = np.cumsum(rng.normal(0.0, 0.05, g.shape), axis=int(seed % 2)) * rng.uniform(0.3, 3.0)
    z[rng.random(g.shape) < 0.08] = np.nan
    z[5:12, 3:20] = np.nan
    anchors = np.array([[0.2, 0.5, 1.0], [1.0, 1.2, 1.0]])  # among the cells: every heading
    for half in ((0.3, 0.225), (0.1, 0.07)):
        c = ClimberConfig(body_half_length_m=half[0], body_half_width_m=half[1])
        got = footprint_known(z, g, c, anchors)
        assert np.array_equal(got, footprint_known_whole_map(z, g, c, anchors))
    assert got.any() and not got.all()


def test_a_hole_in_the_map_is_not_a_cliff_beside_it() -> None:
    """A gently sloping plateau (10 deg, under the Cliff-bot's slope limit) with a hole the size
    of a footprint: the known ground round the hole keeps its slope and is no hazard (filled
    with the map's lowest height, the hole read as a drop and made a band two footprints wide
    round it too steep); where the same hole is a known shaft 20 m deep, the ground round it is
    too steep to stand on."""
    ccfg = ClimberConfig()
    grid = MapGrid(0.0, 0.0, 0.03, 120, 120)
    x, y = grid.centers()
    z = (np.tan(np.radians(10.0)) * y - 2.0).astype(np.float64)
    hole = np.hypot(x - 1.8, y - 1.8) < ccfg.footprint_m
    holed = np.where(hole, np.nan, z)
    g = ground_layers(holed, grid, ccfg)
    ring = ~hole & (np.hypot(x - 1.8, y - 1.8) < ccfg.footprint_m + 0.3)
    assert np.abs(g.slope_deg[ring] - 10.0).max() < 0.5
    assert not g.hazard.any() and not g.rock.any()
    pit = ground_layers(np.where(hole, z - 20.0, z), grid, ccfg)
    assert pit.hazard[ring].any() and (pit.slope_deg[ring] > ccfg.max_slope_deg).any()


def test_the_known_grounds_edge_above_a_drop_is_no_rock_and_a_rock_there_still_is() -> None:
    """The plateau's last decimetres before a lip, the plateau behind them not yet seen: every
    disc centred on known ground over them reaches down the drop, and on those alone they read
    as rocks of the drop's height; the discs centred on the unseen plateau (their known cells)
    hold them. A boulder on that strip, with its ground known round it, is still a rock, and the
    map that knows every cell reads as the codec's relief."""
    grid = MapGrid(-1.5, -1.5, 0.03, 100, 100)
    x, y = grid.centers()
    z = np.where(y > 0, 0.0, np.maximum(-0.8, math.tan(math.radians(80.0)) * y))  # a 0.8 m drop at y = 0
    seen = z.copy()
    seen[y > 0.2] = np.nan  # the plateau more than 0.2 m behind the lip unseen
    cfg = ClimberConfig()
    strip = (y > 0.0) & (y <= 0.2)
    assert not ground_layers(seen, grid, cfg).rock[strip].any()
    from fsw.core.codec.hazard import relief
    old = np.nan_to_num(relief(seen, grid.cell, cfg.rock_disc_m), nan=0.0)  # discs on known centres only
    assert (old[strip] >= 0.5).any()  # what the strip read as: rocks of the drop's height
    bump = np.hypot(x - 0.3, y - 0.1) < 0.08
    whole = z.copy()
    whole[bump] += 0.6  # a boulder on the strip (near the lip the rock test reads it across the steep footprint)
    rock = np.where(np.isfinite(seen), whole, np.nan)
    full_rock = ground_layers(whole, grid, cfg).rock
    assert full_rock[bump].any()
    assert np.array_equal(ground_layers(rock, grid, cfg).rock[bump], full_rock[bump])
    assert np.array_equal(np.nan_to_num(relief(whole, grid.cell, cfg.rock_disc_m, unknown_centres=True)),
                          np.nan_to_num(relief(whole, grid.cell, cfg.rock_disc_m)))
