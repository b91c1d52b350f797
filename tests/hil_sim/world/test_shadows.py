"""Cast shadows from the scenario's sun (issue 14, item 3: shadows; docs/world.md)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hil_sim.world import load_scenario
from hil_sim.world.config import TextureConfig
from hil_sim.world.shadow import cast_shadow
from hil_sim.world.texture import shading

CELL_M = 0.01


def _wall(height_m: float = 0.5) -> np.ndarray:
    h = np.zeros((301, 301), np.float32)
    h[140:161, 140:161] = height_m  # a 20 cm square block in the middle
    return h


@pytest.mark.parametrize("azimuth_deg", [0.0, 90.0, 180.0, 270.0, 45.0])
@pytest.mark.parametrize("elevation_deg", [30.0, 45.0, 60.0])
def test_block_shadow_points_away_from_the_sun_with_the_right_length(azimuth_deg, elevation_deg):
    h = _wall(0.5)
    lit = cast_shadow(h, CELL_M, azimuth_deg, elevation_deg)
    assert lit.shape == h.shape and lit.dtype == np.float32
    assert ((lit >= 0) & (lit <= 1)).all()
    az = math.radians(azimuth_deg)
    away = -np.array([math.cos(az), math.sin(az)])  # ground direction away from the sun
    length_m = 0.5 / math.tan(math.radians(elevation_deg))
    # sample along the line from the block's centre away from the sun
    def lit_at(dist_m: float) -> float:
        x = 150 + away[0] * dist_m / CELL_M
        y = 150 + away[1] * dist_m / CELL_M
        return float(lit[int(round(y)), int(round(x))])
    edge_m = 0.10 * max(abs(away[0]), abs(away[1])) ** -1 if abs(away).max() > 0 else 0.10
    assert lit_at(edge_m + 0.3 * length_m) < 0.5  # well inside the shadow
    assert lit_at(edge_m + 0.8 * length_m) < 0.5
    assert lit_at(edge_m + length_m + 0.05) > 0.5  # past its end (5 cm: tolerance, penumbra)
    # the sun side of the block is lit
    toward = -away
    y, x = int(round(150 + toward[1] * 0.3 / CELL_M)), int(round(150 + toward[0] * 0.3 / CELL_M))
    assert lit[y, x] > 0.5


def test_flat_ground_and_zenith_sun_cast_nothing():
    flat = np.random.default_rng(0).normal(0, 0.001, (200, 200)).astype(np.float32)
    assert (cast_shadow(flat, CELL_M, 30.0, 20.0) > 0.99).all()
    assert (cast_shadow(_wall(), CELL_M, 30.0, 90.0) == 1.0).all()


def test_bad_input_is_refused_with_a_clear_error():
    h = _wall()
    bad = h.copy()
    bad[3, 3] = np.nan
    with pytest.raises(ValueError, match="finite"):
        cast_shadow(bad, CELL_M, 0.0, 45.0)
    with pytest.raises(ValueError, match="elevation"):
        cast_shadow(h, CELL_M, 0.0, 0.0)
    with pytest.raises(ValueError, match="cell_m"):
        cast_shadow(h, float("nan"), 0.0, 45.0)


def test_shadowed_cells_get_the_ambient_light_only():
    h = _wall(0.5)
    cfg = TextureConfig(sun_azimuth_deg=0.0, sun_elevation_deg=45.0, ambient=0.3,
                        cast_shadows=True)
    s = shading(h, CELL_M, cfg)
    plain = shading(h, CELL_M, TextureConfig(sun_azimuth_deg=0.0, sun_elevation_deg=45.0,
                                             ambient=0.3))
    assert np.isclose(s[150, 100], 0.3)  # 40 cm behind the block: in its shadow
    assert np.isclose(plain[150, 100], 0.3 + 0.7 * math.sin(math.radians(45.0)), atol=1e-5)
    assert np.isclose(s[150, 250], plain[150, 250])  # on the sun side: as before


def test_cliff_scenario_casts_shadows_and_is_deterministic():
    w = load_scenario("cliff")
    assert w.config is not None and w.config.texture.cast_shadows
    t = w.config.texture
    lit = cast_shadow(w.ground, w.cell_m, t.sun_azimuth_deg, t.sun_elevation_deg)
    below = w.ground < w.plateau_z - 0.3
    frac = float(np.mean(lit[below] < 0.5))
    assert 0.01 < frac < 0.3, frac  # the rock jumble shades some of the ground below
    again = cast_shadow(w.ground, w.cell_m, t.sun_azimuth_deg, t.sun_elevation_deg)
    assert np.array_equal(lit, again)
    lab = load_scenario("lab")
    assert lab.config is not None and not lab.config.texture.cast_shadows  # lab: unchanged
