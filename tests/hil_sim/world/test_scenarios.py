"""World truth: scenario layouts, the World API, the Cliff-bot and scenario config handling.

Requirements: issue 3, "What to build" items 1 (scenarios lab, cliff, mars, file:PATH) and
2 (fine truth heightfield, natural texture, Cliff-bot with ArUco markers).
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from shapely.geometry import Polygon

from fsw.core.geometry import MapGrid
from fsw.core.localization.fiducials import CliffbotLayout
from fsw.framework.params import ConfigError
from hil_sim.world import ScenarioError, load_scenario
from hil_sim.world.config import load_scenario_config
from hil_sim.world.scenarios import build_world


@pytest.fixture(scope="module")
def lab():
    return load_scenario("lab")


def _plateau_polygon(edge: np.ndarray, up: float = 2.0) -> Polygon:
    return Polygon(np.vstack([edge, [edge[-1, 0], edge[-1, 1] + up], [edge[0, 0], edge[0, 1] + up]]))


def test_lab_layout(lab):
    """Issue 3 item 1 (lab): flat plateau at z=0 around the start, an irregular non-convex
    step edge near y=-0.8 with a 0.3-0.5 m drop, a pit x -0.5..7, y -6.5..-0.8."""
    assert lab.cell_m <= 0.01
    assert lab.rover_start == (0.0, 0.0, 0.0) and lab.plateau_z == 0.0
    xs, ys = np.meshgrid(np.linspace(-1.5, 8.5, 60), np.linspace(-0.2, 2.5, 20))
    assert np.all(lab.height_at(xs, ys) == 0.0)
    assert lab.on_plateau(0.0, 0.0) and not lab.on_plateau(3.0, -3.0)
    edge = lab.edge_xy
    assert edge[0, 0] <= -0.4 and edge[-1, 0] >= 6.9
    assert np.all(np.abs(edge[:, 1] + 0.8) < 0.45)
    fit = np.polyfit(edge[:, 0], edge[:, 1], 1)
    assert np.max(np.abs(np.polyval(fit, edge[:, 0]) - edge[:, 1])) > 0.1  # not straight
    poly = _plateau_polygon(edge)
    assert poly.convex_hull.area - poly.area > 0.1  # not convex
    # The drop: 20 cm past the edge the floor is 0.3-0.5 m down, the plateau 5 cm before it.
    below = lab.ground_at(edge[:, 0], edge[:, 1] - 0.2)
    above = lab.ground_at(edge[:, 0], edge[:, 1] + 0.05)
    inner = (edge[:, 0] > 0.0) & (edge[:, 0] < 6.5)
    assert np.all(above[inner] == 0.0)
    assert 0.3 <= -np.median(below[inner]) <= 0.5
    pit = lab.ground_at(*np.meshgrid(np.linspace(-0.4, 6.9, 50), np.linspace(-6.4, -1.5, 40)))
    assert np.all(pit < -0.05)


def test_lab_three_rock_piles_and_textureless_region(lab):
    """Issue 3 item 1 (lab): three rock piles in the pit and a textureless region in its
    left (low x) part, with constant albedo and no texture."""
    grid = MapGrid(-0.3, -6.3, 0.03, 240, 160)  # the pit floor, clear of its walls
    z = lab.truth_on_grid(grid)
    X, _ = grid.centers()
    cb = lab.cliffbot
    far_from_bot = np.hypot(X - cb.x, grid.centers()[1] - cb.y) > 0.8
    tall = (z > -0.4 + 0.12) & far_from_bot & (z < -0.02)
    n_labels, labels = cv2.connectedComponents(tall.astype(np.uint8))
    sizes = np.bincount(labels.ravel())[1:]
    assert (sizes > 30).sum() == 3
    tl = lab.textureless
    assert tl.any()
    iy, ix = np.nonzero(tl)
    x = lab.x0 + (ix + 0.5) * lab.cell_m
    assert x.max() < 2.5 and x.min() > -0.5  # left part of the pit
    assert np.ptp(lab.albedo[tl]) == 0.0
    assert lab.albedo[~tl].std() > 0.05  # elsewhere: texture
    on_grid = lab.textureless_on_grid(MapGrid(-0.5, -6.5, 0.03, 256, 256))
    assert 0.8 < on_grid.sum() * 0.03**2 / (tl.sum() * lab.cell_m**2) < 1.2


def test_world_api_interpolation_and_grids(lab):
    """World API: height_at is bilinear between cell centres (NaN off the grid);
    truth_on_grid averages the truth over map cells."""
    iy, ix = 400, 500
    xc = lab.x0 + (ix + 0.5) * lab.cell_m
    yc = lab.y0 + (iy + 0.5) * lab.cell_m
    assert lab.height_at(xc, yc) == pytest.approx(lab.height[iy, ix], abs=1e-6)
    mid = lab.height_at(xc + 0.5 * lab.cell_m, yc)
    assert mid == pytest.approx(0.5 * (lab.height[iy, ix] + lab.height[iy, ix + 1]), abs=1e-6)
    assert np.isnan(lab.height_at(-100.0, 0.0))
    grid = MapGrid(-0.5, -6.5, 0.02, 10, 10)
    z = lab.truth_on_grid(grid)
    block = lab.height[150:152, 150:152]  # cell (0, 0) covers truth cells 150..151 (x and y)
    assert z[0, 0] == pytest.approx(block.mean(), abs=1e-5)
    off = lab.truth_on_grid(MapGrid(100.0, 100.0, 0.03, 4, 4))
    assert np.isnan(off).all()


def test_scenarios_are_deterministic_per_seed():
    """Determinism: the same spec and seed give identical worlds; another seed changes the
    texture and details but not the lab layout."""
    cfg, _ = load_scenario_config("lab")
    a, b, c = build_world(cfg, 3), build_world(cfg, 3), build_world(cfg, 4)
    assert np.array_equal(a.height, b.height) and np.array_equal(a.albedo, b.albedo)
    assert not np.array_equal(a.albedo, c.albedo)
    assert np.array_equal(a.height[:, :1] == 0, c.height[:, :1] == 0)
    assert a.height.flags.writeable is False


def test_cliffbot_markers(lab):
    """Issue 3 item 2: the Cliff-bot stands about 3 m from the rover start carrying
    DICT_4X4_50 markers (0.18 m) whose corners are exposed in body and world frames and
    match the flight software's as-built layout (fsw.core.localization.fiducials.CliffbotLayout)."""
    cb = lab.cliffbot
    assert 2.7 < math.hypot(cb.x, cb.y) < 3.3
    assert cb.z == pytest.approx(lab.ground_at(cb.x, cb.y), abs=0.03)
    assert sorted(m.id for m in cb.markers) == [1, 2, 3, 4]
    layout = CliffbotLayout().corners_body()
    for m in cb.markers:
        c = m.corners_world
        sides = np.linalg.norm(np.roll(c, -1, axis=0) - c, axis=1)
        assert np.allclose(sides, 0.18, atol=1e-9)
        assert abs(np.dot(c[1] - c[0], c[3] - c[0])) < 1e-9
        assert np.allclose(cb.body_to_world(m.corners_body), c)
        assert np.allclose(layout[m.id], m.corners_body, atol=1e-9)
    front = cb.marker(1)
    to_rover = np.array([0.0, 0.0]) - front.center_world[:2]
    assert np.dot(front.normal_world[:2], to_rover) > 0  # the front marker faces the rover
    on_top = cb.body_to_world(np.array([[0.2, 0.0, cb.height_m]]))[0]  # clear of the plate
    assert lab.height_at(on_top[0], on_top[1]) == pytest.approx(on_top[2], abs=0.005)
    under_plate = cb.body_to_world(np.array([[-0.05, 0.0, 0.0]]))[0]
    assert lab.height_at(under_plate[0], under_plate[1]) > cb.z + cb.height_m + 0.05


def test_cliff_face_and_edge():
    """Issue 3 item 1 (cliff): steep (~75 deg) irregular face, non-convex edge, rocks below."""
    w = load_scenario("cliff")
    edge = w.edge_xy
    poly = _plateau_polygon(edge[(edge[:, 0] > -0.5) & (edge[:, 0] < 8)])
    assert poly.convex_hull.area - poly.area > 0.2
    slopes = []
    for x, ye in edge[::25]:
        y = np.linspace(ye + 0.02, ye - 0.8, 400)
        z = w.ground_at(np.full_like(y, x), y)
        i0 = np.argmax(z < -0.2)
        i1 = np.argmax(z < -1.2)
        if i0 and i1 and i1 > i0:
            slopes.append(math.degrees(math.atan2(1.0, y[i0] - y[i1])))
    assert 70.0 <= np.median(slopes) <= 80.0
    below = w.ground[(w.y0 + (np.arange(w.shape[0]) + 0.5) * w.cell_m) < -2.0]
    assert np.percentile(below, 99.5) - np.median(below) > 0.15  # a rock jumble


def test_cliff_silt_flats_are_textureless_rock_free_and_below_the_foot():
    """Issue 5 (cliff, Methods 4 vs 5): the cliff world's ``textureless_regions`` are silt
    flats: constant albedo, no rocks on them, only on the ground past the cliff foot; without
    them the same ground is textured."""
    w = load_scenario("cliff")
    tl = w.textureless
    area = tl.sum() * w.cell_m**2
    assert 4.0 < area < 7.0
    assert np.ptp(w.albedo[tl]) == 0.0
    assert w.ground[tl].max() < -1.5  # all below the 1.5 m face
    assert (w.height[tl] == w.ground[tl]).all()  # nothing stands on them (no Cliff-bot)
    # No rocks: inside the flats (clear of the largest rocks' reach from outside) the ground
    # is the bare floor of the same world built without any rocks.
    rockless = load_scenario("cliff?jumble_k=0&background_k=0")
    inner = cv2.erode(tl.astype(np.uint8), np.ones((101, 101), np.uint8)).astype(bool)
    assert inner.sum() > 5000
    assert np.array_equal(w.ground[inner], rockless.ground[inner])
    assert not np.array_equal(w.ground, rockless.ground)  # there are rocks elsewhere
    bare = load_scenario("cliff?textureless_regions=[]")
    assert not bare.textureless.any() and np.ptp(bare.albedo[tl]) > 0.05


def test_textureless_regions_are_validated():
    """A region with a non-positive semi-axis is refused with one line, not a traceback."""
    with pytest.raises(ScenarioError, match="semi-axes must be > 0"):
        load_scenario("lab?textureless_regions=[[1.0,-3.0,0.0,1.0]]")
    with pytest.raises(ConfigError):
        load_scenario("lab?textureless_regions=[[1.0,-3.0]]")


def test_mars_scenario_and_override():
    """Issue 3 item 1 (mars): Viking rocks with coverage k and a seed; k from the spec."""
    a = load_scenario("mars?k=0.16", seed=1)
    b = load_scenario("mars?k=0.02", seed=1)
    assert a.config.mars.k == 0.16 and b.config.mars.k == 0.02
    sel = (slice(100, 500), slice(300, 1000))  # below the scarp
    rough_a = np.percentile(a.ground[sel], 99) - np.median(a.ground[sel])
    rough_b = np.percentile(b.ground[sel], 99) - np.median(b.ground[sel])
    assert rough_a > rough_b
    flat = load_scenario("mars?scarp_drop_m=0")
    assert flat.edge_xy.shape == (0, 2)


def test_file_dem_npy_and_png(tmp_path):
    """Issue 3 item 1 (file:PATH): a .npy DEM in metres and a 16-bit PNG with a scale."""
    y = np.arange(700)[:, None] * 0.01 - 6.0 + 0.005  # cell centres, y -6 .. 1 m
    dem = np.where(y > -1.0, 0.0, -0.5).astype(np.float32) * np.ones((1, 700), np.float32)
    np.save(tmp_path / "step.npy", dem)
    w = load_scenario(f"file:{tmp_path / 'step.npy'}")
    assert w.cell_m == 0.01 and w.plateau_z == 0.0
    assert np.allclose(w.edge_xy[:, 1], -1.0, atol=0.02)
    assert w.safe_side_sign == 1
    d = w.edge_xy[-1] - w.edge_xy[0]
    assert d[0] > 0  # walked along +x with the plateau (y > -1) on its left
    counts = ((dem + 1.0) / 0.002).astype(np.uint16)[::-1]  # north up, 2 mm per count
    cv2.imwrite(str(tmp_path / "step.png"), counts)
    p = load_scenario(f"file:{tmp_path / 'step.png'}?z_scale_m=0.002&z_offset_m=-1.0")
    assert np.allclose(p.ground, w.ground, atol=0.003)
    coarse = dem[::4, ::4].copy()
    np.save(tmp_path / "coarse.npy", coarse)
    c = load_scenario(f"file:{tmp_path / 'coarse.npy'}?cell_m=0.04")
    assert c.cell_m == pytest.approx(0.01) and c.shape == (700, 700)


@pytest.mark.parametrize("content, why", [
    (None, "not found"),
    ("text", "not a NumPy .npy file"),
    ("nan", "NaN"),
    ("3d", "2-D"),
])
def test_file_dem_bad_input_is_a_clear_error(tmp_path, content, why):
    """Issue 3 standards: bad input files give a one-line error, never a traceback."""
    path = tmp_path / "dem.npy"
    if content == "text":
        path.write_text("not an array")
    elif content == "nan":
        np.save(path, np.full((50, 50), np.nan, np.float32))
    elif content == "3d":
        np.save(path, np.zeros((5, 5, 5), np.float32))
    with pytest.raises(ScenarioError, match=why):
        load_scenario(f"file:{path}")


def test_png_must_be_16_bit_and_start_on_dem(tmp_path):
    cv2.imwrite(str(tmp_path / "eight.png"), np.zeros((50, 50), np.uint8))
    with pytest.raises(ScenarioError, match="16-bit"):
        load_scenario(f"file:{tmp_path / 'eight.png'}")
    np.save(tmp_path / "small.npy", np.zeros((50, 50), np.float32))
    with pytest.raises(ScenarioError, match="outside the DEM"):
        load_scenario(f"file:{tmp_path / 'small.npy'}")


@pytest.mark.parametrize("spec, exc, why", [
    ("moon", ScenarioError, "unknown scenario"),
    ("", ScenarioError, "empty"),
    ("lab?drop_m=0.9", ConfigError, "above the maximum"),
    ("lab?no_such_key=1", ConfigError, "no scenario table"),
    ("lab?x_m=1", ConfigError, "ambiguous"),
    ("lab?drop_m", ScenarioError, "not key=value"),
    ("lab?lab.drop_m=deep", ConfigError, "expected a number"),
])
def test_bad_specs_are_refused(spec, exc, why):
    with pytest.raises(exc, match=why):
        load_scenario(spec)
