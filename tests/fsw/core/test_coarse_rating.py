"""Coarse-to-fine next-view search (fsw/core/planning/coarse_rating.py; issue 15 item 1)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from fsw.core.geometry import CameraConfig, MapGrid, MastConfig
from fsw.core.planning.coarse_rating import (
    coarse_factor,
    coarse_visibility,
    coarsen_terrain,
    fine_factor,
    prepare,
    rate_station_coarse_steps,
    rate_views_pooled_steps,
    rate_views_steps,
)
from fsw.core.planning.info_planners import InformationPlanner
from fsw.core.planning.nbv import NbvConfig, info_n_max, rate_station
from fsw.core.planning.planners import PlannerState
from fsw.core.planning.visibility import Terrain, VisibilityConfig, rays_for_cell, terrain_from_map
from fsw.core.steps import run_to_end
from hil_sim.lab.nbv_scene import edge_offset_path, panorama_map, synthetic_edge, synthetic_terrain

GRID = MapGrid(x0=-0.5, y0=-3.5, cell=0.04, nx=110, ny=100)
CAM, MAST, VIS = CameraConfig(), MastConfig(), VisibilityConfig()
FINE_GRID = MapGrid(x0=-0.5, y0=-3.5, cell=0.015, nx=293, ny=267)  # GRID's area at 1.5 cm
FAST = NbvConfig(max_travel_m=1.0, pan_step_deg=30.0, tilts_deg=(-30.0, -50.0))


def _state(grid: MapGrid = GRID) -> PlannerState:
    truth, textured = synthetic_terrain(grid, seed=7)
    emap = panorama_map(truth, textured, grid, CAM, MAST, (1.0, 0.0, 0.0), seed=7)
    path = edge_offset_path(synthetic_edge(), 0.75)
    return PlannerState(emap, (1.0, 0.0, 0.0), (0.0, 0.0, 0.5), path, lambda a, b: True,
                        edge_xy=synthetic_edge())


def test_coarse_factor_rounds_and_disables() -> None:
    assert coarse_factor(0.03, 0.12) == 4
    assert coarse_factor(0.015, 0.12) == 8
    assert coarse_factor(0.03, 0.04) == 1
    for off in (0.0, -1.0, math.nan, math.inf):
        assert coarse_factor(0.03, off) == 1
    fixed = dataclasses.replace(VIS, ray_cell_m=0.0)  # fixed bins: the coarse pass divides them
    assert coarse_visibility(fixed, 4).rays_per_turn == VIS.rays_per_turn // 4
    assert coarse_visibility(fixed, 64).rays_per_turn == 256
    assert coarse_visibility(VIS, 4) == VIS  # scaled bins: the kernel divides by the cell size


def test_rays_scale_with_the_cell() -> None:
    assert rays_for_cell(VIS, VIS.ray_cell_m) == VIS.rays_per_turn
    assert rays_for_cell(VIS, VIS.ray_cell_m / 2) == 2 * VIS.rays_per_turn
    assert rays_for_cell(VIS, VIS.ray_cell_m * 4) == VIS.rays_per_turn // 4
    assert rays_for_cell(VIS, 100.0) == 256 and rays_for_cell(VIS, 1e-6) == 65536
    assert rays_for_cell(dataclasses.replace(VIS, ray_cell_m=0.0), 0.015) == VIS.rays_per_turn


def test_coarsen_terrain_means_spread_and_weight() -> None:
    """Block mean elevation, block spread added to the variance, exponent x factor; a grid
    that is not a multiple of the factor is covered by a padded coarse grid."""
    g = MapGrid(0.0, 0.0, 0.03, 5, 4)
    elev = np.zeros(g.shape)
    elev[0, 0] = 0.4  # one rough block: values 0.4, 0, 0, 0
    sigma = np.full(g.shape, 0.01)
    weight = np.ones(g.shape)
    weight[2:, :] = 0.03  # unknown-like rows
    c = coarsen_terrain(Terrain(g, elev, sigma, weight), 2)
    assert c.grid.shape == (2, 3) and c.grid.cell == pytest.approx(0.06)
    assert c.elev_m[0, 0] == pytest.approx(0.1)
    assert c.sigma_m[0, 0] == pytest.approx(math.sqrt(1e-4 + np.var([0.4, 0, 0, 0])))
    assert c.sigma_m[0, 1] == pytest.approx(0.01)
    assert c.weight[0, 0] == pytest.approx(2.0) and c.weight[1, 0] == pytest.approx(0.06)
    assert c.weight[0, 2] == pytest.approx(1.0)  # half the block lies outside the map
    assert coarsen_terrain(Terrain(g, elev, sigma, weight), 1).grid == g


def test_rate_views_equals_the_exact_station_rating() -> None:
    """The refinement rates each chosen view with the fine kernel: the same H as the exact
    per-station rating of that view (same P_V, same cell values, same field of view)."""
    st = _state()
    terrain = terrain_from_map(st.map.z, st.map.var, GRID, VIS)
    cam = (1.3, 0.0, 1.5)
    yaws, tilts = np.radians([-90.0, -60.0, 0.0]), np.radians([-30.0, -50.0])
    n_max = info_n_max(st.map, FAST)
    ref = rate_station(terrain, cam, yaws, tilts, st.map.n, n_max, st.map.interest, CAM, VIS)
    pick_y, pick_t = np.array([0, 1, 2, 1]), np.array([0, 0, 1, 1])
    r = run_to_end(rate_views_steps(terrain, cam, yaws[pick_y], tilts[pick_t], st.map.n, n_max,
                                    st.map.interest, CAM, VIS))
    want = ref.info_bits[pick_y, pick_t]
    assert want.max() > 10.0  # the views do see unmapped terrain
    np.testing.assert_allclose(r.info_bits, want, rtol=2e-3, atol=0.05)
    np.testing.assert_allclose(r.expected_new_cells, ref.expected_new_cells[pick_y, pick_t],
                               rtol=2e-3, atol=0.05)


def test_coarse_rating_tracks_the_exact_one() -> None:
    """The coarse H of every view of a centre ranks like the exact one (it only chooses which
    views to refine): strong correlation, and the exact best is among the coarse top few."""
    st = _state()
    terrain = terrain_from_map(st.map.z, st.map.var, GRID, VIS)
    cam = (1.3, 0.0, 1.5)
    pans = np.radians(np.arange(-150.0, 151.0, 30.0))
    tilts = np.radians([-30.0, -50.0])
    n_max = info_n_max(st.map, FAST)
    exact = rate_station(terrain, cam, pans, tilts, st.map.n, n_max, st.map.interest, CAM, VIS)
    cs = prepare(terrain, 2, st.map.n, n_max, st.map.interest)
    coarse = run_to_end(rate_station_coarse_steps(cs, cam, pans, tilts, CAM,
                                                  coarse_visibility(VIS, 2)))
    e, c = exact.info_bits.ravel(), coarse.info_bits.ravel()
    assert np.corrcoef(e, c)[0, 1] > 0.95
    assert int(np.argmax(e)) in np.argsort(-c)[:4].tolist()


def test_coarse_to_fine_search_matches_exact_search() -> None:
    """Issue 15: the coarse-to-fine search chooses the exhaustive search's view on this
    state, with the exact kernel's H for it, in fewer steps; coarse_cell_m = 0 is exhaustive."""
    st = _state()
    c2f = InformationPlanner("5", dataclasses.replace(FAST, coarse_cell_m=0.08,
                                                         refine_views=3), CAM, MAST,
                             use_interest=True)
    exact = InformationPlanner("5", dataclasses.replace(FAST, coarse_cell_m=0.0), CAM, MAST,
                               use_interest=True)
    a, b = c2f.next_view(st), exact.next_view(st)
    assert a is not None and b is not None
    assert a.rover == b.rover and a.joints == b.joints
    assert a.info_bits == pytest.approx(b.info_bits, rel=2e-3)
    assert a.utility == pytest.approx(b.utility, rel=2e-3)
    assert c2f.last_centres <= 3 < exact.last_centres  # centres refined, centres rated


def test_fine_factor_never_pools_past_the_fine_cell() -> None:
    assert fine_factor(0.015, 0.03) == 2 and fine_factor(0.01, 0.03) == 3
    assert fine_factor(0.03, 0.03) == 1 and fine_factor(0.02, 0.03) == 1 and fine_factor(0.04, 0.03) == 1
    for off in (0.0, -1.0, math.nan, math.inf):
        assert fine_factor(0.01, off) == 1


def test_pooled_refinement_tracks_the_exact_one() -> None:
    """On a map finer than fine_cell_m the refining pass pools P_V to it and keeps every map
    cell's own terms: H and expected new cells near the exact kernel's (a block's spread of
    heights softens its occlusion: a single view differs by up to ~5 % of the best view's), and the
    search chooses the exact search's view (a 1.5 cm map pooled to 3 cm, as a 512 x 512
    lab map is)."""
    st = _state(FINE_GRID)
    terrain = terrain_from_map(st.map.z, st.map.var, FINE_GRID, VIS)
    cam = (1.3, 0.0, 1.5)
    yaws, tilts = np.radians([-90.0, -60.0, 0.0, -30.0]), np.radians([-30.0, -50.0, -30.0, -50.0])
    n_max = info_n_max(st.map, FAST)
    exact = run_to_end(rate_views_steps(terrain, cam, yaws, tilts, st.map.n, n_max, st.map.interest,
                                        CAM, VIS))
    cs = prepare(terrain, 2, st.map.n, n_max, st.map.interest)
    pooled = run_to_end(rate_views_pooled_steps(cs, cam, yaws, tilts, CAM, coarse_visibility(VIS, 2)))
    assert exact.info_bits.min() > 10.0
    assert pooled.cells_rated == exact.cells_rated  # the same map cells in view
    for got, want in ((pooled.info_bits, exact.info_bits),
                      (pooled.expected_new_cells, exact.expected_new_cells)):
        np.testing.assert_allclose(got, want, atol=0.05 * want.max())
        assert got.sum() == pytest.approx(want.sum(), rel=0.05)
    base = dataclasses.replace(FAST, coarse_cell_m=0.12, refine_views=3)
    fine = InformationPlanner("5", dataclasses.replace(base, fine_cell_m=0.03), CAM, MAST, use_interest=True)
    full = InformationPlanner("5", dataclasses.replace(base, fine_cell_m=0.0), CAM, MAST, use_interest=True)
    a, b = fine.next_view(st), full.next_view(st)
    assert a is not None and b is not None
    assert a.rover == b.rover and a.joints == b.joints
    assert a.utility == pytest.approx(b.utility, rel=0.05) and a.utility != b.utility  # pooled, not exact
