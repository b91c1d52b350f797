"""P_V (docs/algorithm.md §3.1, Eq 4): the brute-force oracle, the fast kernel against it, culling."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.stats import norm

from fsw.core.geometry import CameraConfig, CameraPose, MapGrid, MastConfig
from fsw.core.planning.visibility import (
    Terrain,
    VisibilityConfig,
    in_view,
    terrain_from_heights,
    terrain_from_map,
)
from fsw.core.planning.visibility_kernel import pv_fast
from hil_sim.lab.nbv_scene import panorama_map, synthetic_terrain
from hil_sim.lab.pv_oracle import pv_reference

GRID = MapGrid(x0=-0.5, y0=-3.5, cell=0.04, nx=110, ny=100)
VIS = VisibilityConfig()


def _targets(grid: MapGrid, cam: tuple[float, float, float], r_min: float = 0.3,
             r_max: float = 5.8) -> tuple[np.ndarray, np.ndarray]:
    xs, ys = grid.centers()
    d = np.hypot(xs - cam[0], ys - cam[1])
    return np.nonzero((d > r_min) & (d < r_max))


def _mae(terrain: Terrain, cam: tuple[float, float, float], cfg: VisibilityConfig = VIS
         ) -> tuple[float, float]:
    iy, ix = _targets(terrain.grid, cam)
    ref = pv_reference(terrain, cam, iy, ix)
    fast = pv_fast(terrain, cam, iy, ix, cfg)
    return float(np.abs(fast - ref).mean()), float(ref.mean())


def test_reference_single_occluder_is_one_phi_factor() -> None:
    """Issue 5 item 1: Eq 4 on a ray along a grid row: one raised cell gives exactly one
    factor Phi((ray - Ob)/s) with the ray height at the cell's midpoint."""
    g = MapGrid(0.0, 0.0, 0.1, 40, 5)
    h = np.full(g.shape, -5.0)
    h[2, 20] = 0.5  # occluder cell, centre x = 2.05
    s = np.full(g.shape, 0.001)  # every other factor is exactly 1
    s[2, 20] = 0.05
    terrain = Terrain(g, h, s, np.ones(g.shape))
    cam = (0.25, 0.25, 1.0)  # centre of cell (2, 2)
    pv = pv_reference(terrain, cam, np.array([2]), np.array([35]))  # target centre x = 3.55
    t_mid = (3.55 - 2.05) / (3.55 - 0.25)
    ray = -5.0 + t_mid * (1.0 + 5.0)
    assert pv[0] == pytest.approx(norm.cdf((ray - 0.5) / 0.05), rel=1e-6)


def test_reference_ignores_corner_touches_and_target_cell() -> None:
    """Issue 5 item 1: a diagonal ray through cell corners does not count the corner-touching
    cells, and the target's own cell is never a factor."""
    g = MapGrid(0.0, 0.0, 0.1, 10, 10)
    h = np.zeros(g.shape)
    h[3, 4] = h[4, 3] = 5.0  # touch the diagonal only at the corner (0.4, 0.4)
    terrain = Terrain(g, h, np.full(g.shape, 0.01), np.ones(g.shape))
    pv = pv_reference(terrain, (0.05, 0.05, 2.0), np.array([7, 3]), np.array([7, 4]))
    assert pv[0] > 0.999  # (7, 7) seen along the diagonal
    assert pv[1] > 0.999  # the tall cell itself is the target


def test_reference_unknown_exponent_and_occlusion() -> None:
    """§3.1 choice: an unknown cell's factor is raised to cell/corr_len; known terrain above
    the ray occludes; unknown stretches give the paper's ~0.5 per crossing when corr = cell."""
    g = MapGrid(0.0, 0.0, 0.03, 120, 3)
    z = np.full(g.shape, np.nan)
    z[:, :4] = 0.0
    var = np.where(np.isfinite(z), 1e-4, np.inf)
    cam = (0.045, 0.045, 0.2)
    tgt = (np.array([1]), np.array([110]))
    lit = terrain_from_map(z, var, g, VisibilityConfig(prior_corr_len_m=0.03))
    soft = terrain_from_map(z, var, g, VisibilityConfig(prior_corr_len_m=0.3))
    p_lit, p_soft = pv_reference(lit, cam, *tgt)[0], pv_reference(soft, cam, *tgt)[0]
    assert p_lit < 1e-3 < p_soft
    assert p_soft == pytest.approx(p_lit ** 0.1, rel=1e-6)
    wall = np.zeros(g.shape)
    wall[:, 60] = 1.0
    blocked = terrain_from_heights(wall, g, 0.01)
    assert pv_reference(blocked, cam, *tgt)[0] < 1e-6


def test_kernel_matches_reference_on_known_terrain_with_occluders() -> None:
    """Issue 5 item 2: mean |P_V fast - P_V reference| <= 0.05 (we hold it to 0.02) on a
    fully known synthetic scene: step edge, pit, rocks."""
    truth, _ = synthetic_terrain(GRID, seed=1)
    terrain = terrain_from_heights(truth, GRID, 0.01)
    for cam in ((0.3, 0.0, 1.5), (2.0, -0.2, 1.2)):
        mae, mean = _mae(terrain, cam)
        assert mae <= 0.02, (cam, mae)
        assert 0.1 < mean < 0.95  # the scene has both visible and occluded cells


def test_kernel_matches_reference_on_partially_mapped_state() -> None:
    """Issue 5 item 2: same bound with unknown regions (prior elevation, prior sigma), both
    for the default correlation length and for the literal per-cell Eq 4."""
    truth, textured = synthetic_terrain(GRID, seed=2)
    emap = panorama_map(truth, textured, GRID, CameraConfig(), MastConfig(), (0.0, 0.0, 0.0))
    assert 0.1 < emap.mapped.mean() < 0.9
    for cfg in (VIS, VisibilityConfig(prior_corr_len_m=GRID.cell)):
        terrain = terrain_from_map(emap.z, emap.var, GRID, cfg)
        mae, _ = _mae(terrain, (1.0, -0.1, 1.5), cfg)
        assert mae <= 0.02, mae


@settings(max_examples=6, deadline=None)
@given(x=st.floats(-1.5, 4.5), y=st.floats(-4.0, 0.5), z=st.floats(0.6, 2.0))
def test_kernel_matches_reference_anywhere(x: float, y: float, z: float) -> None:
    """Issue 5 item 2: cameras anywhere, including outside the map and near its border."""
    truth, _ = synthetic_terrain(GRID, seed=3)
    terrain = terrain_from_heights(truth, GRID, 0.02)
    iy, ix = _targets(GRID, (x, y, z))
    if iy.size == 0:
        return
    ref = pv_reference(terrain, (x, y, z), iy, ix)
    fast = pv_fast(terrain, (x, y, z), iy, ix, VIS)
    assert np.abs(fast - ref).mean() <= 0.03


def test_kernel_empty_and_degenerate_inputs() -> None:
    """Edge cases: no targets; a target under the camera."""
    terrain = terrain_from_heights(np.zeros(GRID.shape), GRID, 0.01)
    assert pv_fast(terrain, (0.0, 0.0, 1.0), np.array([], int), np.array([], int), VIS).size == 0
    iy, ix, _ = GRID.cell_index(np.array([0.0]), np.array([0.0]))
    assert pv_fast(terrain, (0.0, 0.0, 1.0), iy, ix, VIS)[0] == pytest.approx(1.0)


def test_terrain_rejects_bad_arrays() -> None:
    """Bad input: wrong shapes or non-finite terrain raise ValueError, not garbage."""
    with pytest.raises(ValueError):
        Terrain(GRID, np.zeros((3, 3)), np.ones((3, 3)), np.ones((3, 3)))
    with pytest.raises(ValueError):
        terrain_from_heights(np.full(GRID.shape, np.nan), GRID, 0.01)


def test_prior_fills_unknown_from_known_and_empty_map_uses_default() -> None:
    """§3.1 choice: unknown cells take an elevation interpolated from known ones."""
    z = np.full(GRID.shape, np.nan)
    z[:, :10] = -0.4
    t = terrain_from_map(z, np.where(np.isfinite(z), 1e-4, np.inf), GRID, VIS)
    assert np.allclose(t.elev_m, -0.4) and (t.sigma_m[:, 20:] == VIS.prior_sigma_m).all()
    empty = terrain_from_map(np.full(GRID.shape, np.nan), np.full(GRID.shape, np.inf), GRID,
                             VisibilityConfig(default_elevation_m=0.3))
    assert np.allclose(empty.elev_m, 0.3)


def test_in_view_culls_field_and_depth_of_field() -> None:
    """§3.1: P_V = 0 outside the field of view and the depth of field."""
    cam = CameraConfig()
    pose = CameraPose.from_pan_tilt(0.0, 0.0, 1.0, 0.0, 0.0)  # looking along +x, level
    pts = np.array([[2.0, 0.0, 1.0], [-2.0, 0.0, 1.0], [0.5, 0.0, 1.0], [6.0, 0.0, 1.0],
                    [2.0, 2.0 * math.tan(math.radians(cam.hfov_deg / 2)) + 0.05, 1.0],
                    [2.0, 0.0, 1.0 + 2.0 * math.tan(cam.vfov_rad / 2) + 0.05]])
    assert in_view(pose, cam, pts).tolist() == [True, False, False, False, False, False]
