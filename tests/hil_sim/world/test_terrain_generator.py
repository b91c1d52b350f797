"""The terrain generator (issue 13 item 5): a seeded scenario family of sloped, rocky ground
below an irregular cliff edge 0.3-2 m from the rover's wheels, with textureless patches.

Requirements: same spec + seed gives the same world, another seed another; the slope, edge
distance, rock coverage and patches are what the parameters say; bad parameters are refused
with one line (exit 2 at the CLI); the home scenarios are unchanged by the new kind.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from fsw.framework.params import ConfigError
from hil_sim.cli import main
from hil_sim.world import ScenarioError, load_scenario
from hil_sim.world.config import load_scenario_config
from hil_sim.world.scenarios import build_world
from hil_sim.world.terrain import FOOTPRINT_HALF_WIDTH_M


def _build(spec: str, seed: int):
    cfg, _ = load_scenario_config(spec)
    return build_world(cfg, seed)  # uncached: determinism is checked on fresh builds


def test_same_seed_same_world_other_seed_other_world():
    a, b = _build("terrain", 3), _build("terrain", 3)
    assert np.array_equal(a.height, b.height) and np.array_equal(a.albedo, b.albedo)
    assert np.array_equal(a.edge_xy, b.edge_xy) and np.array_equal(a.textureless, b.textureless)
    c = _build("terrain", 4)
    assert not np.array_equal(a.height, c.height)


@pytest.mark.parametrize("slope_deg, azimuth_deg", [(0.0, 0.0), (8.0, 30.0), (12.0, 250.0)])
def test_regional_slope_and_direction(slope_deg, azimuth_deg):
    w = load_scenario(f"terrain?slope_deg={slope_deg}&slope_azimuth_deg={azimuth_deg}"
                      "&plateau_k=0&relief_m=0", seed=1)
    # Plane fit over the rock-free, relief-free plateau: the tilt and its downhill direction.
    iy, ix = np.nonzero(w.plateau)
    pick = np.random.default_rng(0).choice(iy.size, 5000, replace=False)
    x = w.x0 + (ix[pick] + 0.5) * w.cell_m
    y = w.y0 + (iy[pick] + 0.5) * w.cell_m
    a = np.column_stack([x, y, np.ones_like(x)])
    gx, gy, _ = np.linalg.lstsq(a, w.ground[iy[pick], ix[pick]], rcond=None)[0]
    assert math.degrees(math.atan(math.hypot(gx, gy))) == pytest.approx(slope_deg, abs=0.05)
    if slope_deg > 0:
        downhill = math.degrees(math.atan2(-gy, -gx)) % 360
        assert abs((downhill - azimuth_deg + 180) % 360 - 180) < 0.5
    assert w.ground_at(0.0, 0.0) == pytest.approx(0.0, abs=3e-3)  # zero at the start (cell centre)


@pytest.mark.parametrize("distance", [0.3, 0.45, 1.2, 2.0])
def test_edge_distance_from_the_wheels(distance):
    w = load_scenario(f"terrain?edge_distance_m={distance}", seed=2)
    near = np.abs(w.edge_xy[:, 0]) <= 1.0
    gap = -FOOTPRINT_HALF_WIDTH_M - float(w.edge_xy[near, 1].max())
    assert gap == pytest.approx(distance, abs=0.011)
    assert w.plateau[int(-w.y0 / w.cell_m), int(-w.x0 / w.cell_m)]  # the start is on it


@pytest.mark.parametrize("bearing, distance", [(0.0, 0.2), (-45.0, 0.35)])
def test_edge_ahead_and_diagonal_at_its_distance_from_the_footprint(bearing, distance):
    """``edge_bearing_deg`` turns the edge about the start: ahead (0) it is ``distance`` past the
    bumper, ahead-right (-45) past the front-right corner's reach; the plateau's boundary in that
    direction is there, and the start is on the plateau."""
    w = load_scenario(f"terrain?edge_distance_m={distance}&edge_bearing_deg={bearing}&slope_deg=0", seed=2)
    b = math.radians(bearing)
    reach = 0.45 * abs(math.cos(b)) + FOOTPRINT_HALF_WIDTH_M * abs(math.sin(b))
    normal = np.array([math.cos(b), math.sin(b)])
    along = np.abs(w.edge_xy @ np.array([-normal[1], normal[0]])) <= 1.0
    gap = float((w.edge_xy[along] @ normal).min()) - reach
    assert gap == pytest.approx(distance, abs=0.011)
    assert w.plateau[int(-w.y0 / w.cell_m), int(-w.x0 / w.cell_m)]
    near = w.edge_xy[along][int(np.argmin(w.edge_xy[along] @ normal))]  # its closest point
    for step, on_top in ((-0.05, True), (0.05, False)):  # the plateau ends there
        x, y = near + step * normal
        assert w.plateau[int((y - w.y0) / w.cell_m), int((x - w.x0) / w.cell_m)] == on_top


@pytest.mark.slow
def test_drawn_distance_covers_the_range():
    gaps = []
    for seed in range(20):
        w = load_scenario("terrain", seed=seed)
        near = np.abs(w.edge_xy[:, 0]) <= 1.0
        gaps.append(-FOOTPRINT_HALF_WIDTH_M - float(w.edge_xy[near, 1].max()))
    assert min(gaps) >= 0.29 and max(gaps) <= 2.01 and max(gaps) - min(gaps) > 0.8


def test_rocks_below_the_edge_follow_the_coverage_and_patches_are_bare():
    lo = load_scenario("terrain?k=0.07&slope_deg=0&textureless_count=2", seed=5)
    hi = load_scenario("terrain?k=0.16&slope_deg=0&textureless_count=2", seed=5)
    below = ~lo.plateau & (lo.y0 + (np.arange(lo.shape[0])[:, None] + 0.5) * lo.cell_m < -3.0)
    # Rocks stand above the rolling ground: more coverage, more cells well above the median.
    rough_lo = (lo.ground[below] > np.median(lo.ground[below]) + 0.1).mean()
    rough_hi = (hi.ground[below] > np.median(hi.ground[below]) + 0.1).mean()
    assert rough_hi > 1.5 * rough_lo > 0
    assert lo.textureless.sum() > 0 and not (lo.textureless & lo.plateau).any()
    none = load_scenario("terrain?textureless_count=0", seed=5)
    assert not none.textureless.any()


@pytest.mark.parametrize("spec, exc, why", [
    ("terrain?slope_deg=13", ConfigError, "above the maximum"),
    ("terrain?slope_deg=-2", ConfigError, "below the minimum"),
    ("terrain?edge_distance_m=0.1", ScenarioError, "0.15..2"),
    ("terrain?edge_bearing_deg=200", ConfigError, "above the maximum"),
    ("terrain?edge_distance_m=3", ConfigError, "above the maximum"),
    ("terrain?k=0.9", ConfigError, "above the maximum"),
    ("terrain?textureless_count=1.5", ConfigError, "integer"),
    ("terrain?nope=1", ConfigError, "no scenario table"),
])
def test_bad_parameters_are_refused(spec, exc, why):
    with pytest.raises(exc, match=why):
        load_scenario(spec, seed=0)


def test_bad_parameter_exits_2_with_one_line(tmp_path, capsys):
    rc = main(["render", "--scenario", "terrain?slope_deg=30", "--out", str(tmp_path / "o")])
    out = capsys.readouterr()
    text = (out.out + out.err).strip()
    assert rc == 2 and len(text.splitlines()) == 1 and "above the maximum 12.0 deg" in text


def test_home_scenarios_unchanged_by_the_new_kind():
    """The lab keeps its layout: level plateau at 0, edge near y = -0.8."""
    lab = load_scenario("lab")
    assert lab.plateau_z == 0.0 and abs(float(np.median(lab.edge_xy[:, 1])) + 0.8) < 0.15


@pytest.mark.slow
def test_drawn_parameters_are_recorded_and_in_range():
    slopes = []
    for seed in range(8):
        w = load_scenario("terrain?slope_deg=-1", seed=seed)
        assert 0.0 <= w.drawn["slope_deg"] <= 12.0 and 0.0 <= w.drawn["slope_azimuth_deg"] < 360.0
        assert 0.3 <= w.drawn["edge_distance_m"] <= 2.0
        slopes.append(w.drawn["slope_deg"])
    assert max(slopes) - min(slopes) > 3.0
