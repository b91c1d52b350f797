"""Method 5's accuracy weight (docs/algorithm.md §3.2 choice, issue 30 item 2) and the expected new
cells as the obtained count's own quantity (issue 30 item 3)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from fsw.core.geometry import CameraConfig, MapGrid, MastConfig
from fsw.core.planning.coarse_rating import prepare, rate_station_coarse_steps, rate_views_steps
from fsw.core.planning.nbv import AccuracyModel, NbvConfig, rate_station
from fsw.core.planning.visibility import VisibilityConfig, terrain_from_map
from fsw.core.steps import run_to_end
from hil_sim.lab.nbv_scene import panorama_map, synthetic_terrain

GRID = MapGrid(x0=-0.5, y0=-3.5, cell=0.04, nx=110, ny=100)
CAM = CameraConfig()
ACC = AccuracyModel.of(NbvConfig(accuracy_sigma_m=0.03), CAM)


def test_the_share_of_variance_a_view_removes() -> None:
    assert AccuracyModel.of(NbvConfig(), CAM) is None  # off by default: Methods 3-5 rate as before
    assert ACC is not None
    unknown = np.array([0.25, 0.25, 0.25])
    # new ground below a 1.5 m camera at 1.5, 3 and 5 m: farther is worth less
    rel = np.array([[1.0, 0.0, -1.5], [2.6, 0.0, -1.5], [4.8, 0.0, -1.5]])
    q = ACC.share(rel, unknown)
    assert 0.0 < q[2] < q[1] < q[0] < 1.0
    sz = 0.5 * np.linalg.norm(rel[2]) * 1.5 / (CAM.focal_px * CAM.baseline_m)
    assert q[2] == pytest.approx(0.03**2 / (0.03**2 + sz**2))
    # a cell already known to 2 mm gains little from the same view; one known to 5 cm as much as new ground
    assert ACC.share(rel[:1], np.array([0.002]))[0] < 0.2 * q[0]
    assert ACC.share(rel[:1], np.array([0.05]))[0] == pytest.approx(q[0])


def test_rating_with_the_accuracy_weight() -> None:
    """Bits fall where the view is far, the expected new cells do not change (they are counts); the
    coarse and the exact rating apply the same weight."""
    truth, textured = synthetic_terrain(GRID, seed=4)
    emap = panorama_map(truth, textured, GRID, CAM, MastConfig(), (0.0, 0.0, 0.0))
    vis = VisibilityConfig()
    terrain = terrain_from_map(emap.z, emap.var, GRID, vis)
    cam = (1.2, -0.05, 1.5)
    yaws, tilts = np.radians([-90.0, -45.0]), np.radians([-30.0, -45.0])
    plain = rate_station(terrain, cam, yaws, tilts, emap.n, 2, emap.interest, CAM, vis)
    acc = rate_station(terrain, cam, yaws, tilts, emap.n, 2, emap.interest, CAM, vis, accuracy=ACC)
    assert (acc.info_bits < plain.info_bits).all() and acc.info_bits.min() > 0.0
    np.testing.assert_allclose(acc.expected_new_cells, plain.expected_new_cells)
    # a shallower tilt looks farther: it loses a larger share of its bits
    assert acc.info_bits[0, 0] / plain.info_bits[0, 0] < acc.info_bits[0, 1] / plain.info_bits[0, 1]
    exact = run_to_end(rate_views_steps(terrain, cam, yaws, np.full(2, tilts[1]), emap.n, 2, emap.interest,
                                        CAM, vis, accuracy=ACC))
    np.testing.assert_allclose(exact.info_bits, acc.info_bits[:, 1], rtol=0.03)
    coarse = run_to_end(rate_station_coarse_steps(prepare(terrain, 3, emap.n, 2, emap.interest, ACC), cam,
                                                  yaws, tilts, CAM, dataclasses.replace(vis, rays_per_turn=1024)))
    plain_c = run_to_end(rate_station_coarse_steps(prepare(terrain, 3, emap.n, 2, emap.interest), cam,
                                                   yaws, tilts, CAM, dataclasses.replace(vis, rays_per_turn=1024)))
    assert (coarse.info_bits < plain_c.info_bits).all()
    np.testing.assert_allclose(coarse.info_bits / plain_c.info_bits, acc.info_bits / plain.info_bits, rtol=0.15)
