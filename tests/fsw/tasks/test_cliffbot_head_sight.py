"""What the Cliff-bot's head scan sees from a standing and the ground its next step needs
(fsw.tasks.cliffbot.head_sight; docs/team.md, "Approach: making the unknown known")."""

from __future__ import annotations

import numpy as np

from fsw.core.geometry import MapGrid, MapGridConfig
from fsw.core.team.climber_ground import ClimberConfig
from fsw.sections import CliffbotSensingConfig
from fsw.tasks.cliffbot.head_sight import needed_cells, scan_sees

GRID = MapGrid.from_config(MapGridConfig(origin_x_m=-2.0, origin_y_m=-2.0, cell_m=0.04, nx=100, ny=100))
# anchors up the +y side: the body hangs heading -y (body_yaw), its front toward -y
ANCHORS = np.array([[-1.5, 1.8, 0.3], [1.5, 1.8, 0.3]])
CCFG = ClimberConfig()
HERE = np.array([0.0, 0.0])
OLD_SCAN = CliffbotSensingConfig(pan_deg=(0.0, 45.0, 90.0, 135.0, 180.0, -135.0, -90.0, -45.0, 25.0, -25.0),
                                 tilts_deg=(-40.0,) * 8 + (-75.0, -75.0), places=())


def _cells(points: list[tuple[float, float]]) -> np.ndarray:
    out = np.zeros(GRID.shape, bool)
    for x, y in points:
        iy, ix, _ = GRID.cell_index(np.array([x]), np.array([y]))
        out[int(iy[0]), int(ix[0])] = True
    return out


def test_the_body_hides_the_ground_beside_its_middle_and_the_range_ends_the_view() -> None:
    z = np.zeros(GRID.shape)
    sc = CliffbotSensingConfig()
    beside = _cells([(0.4, 0.0), (-0.4, 0.0)])  # 0.4 m beside the body's middle (half width 0.235)
    ahead = _cells([(0.0, -1.0), (0.3, -0.8)])  # ahead, down the heading
    far = _cells([(0.0, -1.4)])  # 1.05 m from the front head
    assert not scan_sees(z, GRID, CCFG, ANCHORS, sc, HERE, beside).any()
    assert scan_sees(z, GRID, CCFG, ANCHORS, sc, HERE, ahead).sum() == 2
    assert scan_sees(z, GRID, CCFG, ANCHORS, sc, HERE, far).sum() == 1
    short = CliffbotSensingConfig(max_range_m=1.0)
    assert not scan_sees(z, GRID, CCFG, ANCHORS, short, HERE, far).any()  # out of the camera's usable range
    unknown_here = z.copy()
    unknown_here[45:55, 45:55] = np.nan
    assert not scan_sees(unknown_here, GRID, CCFG, ANCHORS, sc, HERE, ahead).any()  # no ground under it: no rating


def test_the_scan_sees_the_ground_in_front_of_the_body_and_beside_its_front_corners() -> None:
    """The ground the next nodes' footprints need first: the strip in front of the front end
    (the body's box ends 0.31 m ahead of its centre, the head stands 0.45 m ahead) and beside
    the front corners; the scan that looked ahead only from the front end and sideways only from
    the rear end left it unseen."""
    z = np.zeros(GRID.shape)
    strip = _cells([(x, y) for x in np.arange(-0.3, 0.31, 0.1) for y in (-0.34, -0.38)])
    corners = _cells([(x, y) for x in (-0.45, 0.45) for y in (-0.2, -0.3)])
    sc = CliffbotSensingConfig()
    assert scan_sees(z, GRID, CCFG, ANCHORS, sc, HERE, strip).sum() == strip.sum()
    assert scan_sees(z, GRID, CCFG, ANCHORS, sc, HERE, corners).sum() == corners.sum()
    assert scan_sees(z, GRID, CCFG, ANCHORS, OLD_SCAN, HERE, strip).sum() < strip.sum()
    assert scan_sees(z, GRID, CCFG, ANCHORS, OLD_SCAN, HERE, corners).sum() < corners.sum()


def test_the_next_step_needs_the_unknown_ground_of_its_footprints_and_tethers() -> None:
    z = np.zeros(GRID.shape)
    none = np.zeros(GRID.shape, bool)
    target = np.array([0.0, -1.5])
    assert not needed_cells(z, none, GRID, CCFG, ANCHORS, HERE, target).any()  # all known: nothing needed
    ahead = z.copy()
    ahead[GRID.centers()[1] < -0.4] = np.nan  # the ground ahead of the front end unknown
    need = needed_cells(ahead, none, GRID, CCFG, ANCHORS, HERE, target)
    assert need.any() and np.isnan(ahead[need]).all()
    assert not need[GRID.centers()[1] < -0.4 - CCFG.body_half_length_m - 4 * CCFG.node_m].any()  # the next step only
    behind = z.copy()
    behind[(GRID.centers()[1] > 1.0)] = np.nan  # the ground under the tethers, up toward the anchors, unknown
    assert needed_cells(behind, none, GRID, CCFG, ANCHORS, HERE, target).sum() > 0
    carried = none.copy()
    carried[GRID.centers()[1] < -0.4] = True  # a height there, but no sensor measured it
    assert needed_cells(z, carried, GRID, CCFG, ANCHORS, HERE, target).sum() == need.sum()
    # a target behind: the nodes nearer it are up the slope, their footprints known
    assert not needed_cells(ahead, none, GRID, CCFG, ANCHORS, HERE, np.array([0.0, 1.5])).any()


def test_a_hole_in_mapped_ground_is_rated_where_its_neighbours_lie() -> None:
    """A cell the views left unknown among ground they mapped (a cell on a drop past a ledge) lies
    with its neighbours, not on the body's ground plane: 2.5 m down the drop it is beyond the
    camera's range from the ledge, 1 m down it is in the steep view; an unknown cell with no
    known ground round it is still rated on the body's plane."""
    sc = CliffbotSensingConfig()
    _, Y = GRID.centers()
    hole = _cells([(0.0, -1.1)])
    for drop_m, seen in ((2.5, 0), (1.0, 1)):
        z = np.where(Y > -0.7, 0.0, -drop_m)
        z[hole] = np.nan
        assert scan_sees(z, GRID, CCFG, ANCHORS, sc, HERE, hole).sum() == seen
    beyond = np.where(Y > -0.7, 0.0, np.nan)  # all of the drop unknown: the body's plane carried on
    assert scan_sees(beyond, GRID, CCFG, ANCHORS, sc, HERE, hole).sum() == 1
