"""View rating (docs/algorithm.md §3.2-§3.6): H, interest function, culling, motion, utility, end."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fsw.core.geometry import CameraConfig, CameraPose, MapGrid, MastConfig
from fsw.core.map.elevation_map import ElevationMap, FusionConfig
from fsw.core.planning.nbv import (
    NbvConfig,
    cell_values,
    end_reason,
    h2,
    localization_sigma,
    motion_cost,
    predicted_visibility,
    rate_station,
    utility,
    view_sums,
)
from fsw.core.planning.visibility import (
    VisibilityConfig,
    cell_points,
    in_view,
    terrain_from_map,
)
from fsw.framework.params import ConfigError, build
from hil_sim.lab.nbv_scene import panorama_map, synthetic_terrain
from hil_sim.lab.pv_oracle import pv_reference

GRID = MapGrid(x0=-0.5, y0=-3.5, cell=0.04, nx=110, ny=100)
CAM = CameraConfig()
CFG = NbvConfig()


def test_h2_shape() -> None:
    """§3.2: binary entropy, 0 at 0 and 1, 1 bit at 1/2."""
    assert h2(np.array([0.0, 0.5, 1.0])).tolist() == pytest.approx([0.0, 1.0, 0.0])


def test_information_zero_for_fully_measured_cells() -> None:
    """Issue 5 item 1: H is zero for cells with n = n_max, whatever P_V."""
    bits, new = cell_values(np.array([1.0, 0.7, 0.2]), np.array([10, 10, 10]), 10, None)
    assert (bits == 0).all() and (new == 0).all()


@settings(max_examples=25, deadline=None)
@given(p1=st.floats(0, 1), p2=st.floats(0, 1), n=st.integers(0, 9))
def test_information_monotone_in_pv(p1: float, p2: float, n: int) -> None:
    """Issue 5 item 1: h2(P_V/2) and so H rise with P_V, and fall with n."""
    lo, hi = sorted((p1, p2))
    b, _ = cell_values(np.array([lo, hi]), np.array([n, n]), 10, None)
    assert b[0] <= b[1] + 1e-12
    b_more, _ = cell_values(np.array([hi]), np.array([n + 1]), 10, None)
    assert b_more[0] <= b[1] + 1e-12


def test_interest_lowers_h_for_visible_misses_but_not_occluded() -> None:
    """Issue 5 item 1 / §3.4: after repeated misses a plainly visible cell loses its H while
    a likely-occluded one keeps most of it (the map's Eq 5 update, then Eq 3)."""
    g = MapGrid(0.0, 0.0, 1.0, 2, 1)
    emap = ElevationMap(g, FusionConfig(interest_beta=1.0))
    pv = np.array([[0.95, 0.05]])
    for _ in range(5):
        emap.record_misses(pv, hit=np.zeros(g.shape, bool))
    plain, _ = cell_values(pv.ravel(), emap.n.ravel(), emap.n_max, None)
    with_if, _ = cell_values(pv.ravel(), emap.n.ravel(), emap.n_max, emap.interest.ravel())
    assert with_if[0] < 0.05 * plain[0]  # visible and missed: interest gone
    assert with_if[1] > 0.7 * plain[1]  # occluded: still interesting


def test_view_sums_cull_exactly_like_in_view() -> None:
    """§3.1 culling: the batched pan/tilt masks agree with ``in_view`` cell by cell."""
    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.uniform(-6, 6, 4000), rng.uniform(-6, 6, 4000),
                           rng.uniform(-1.5, 0.5, 4000)])
    cam = np.array([0.2, -0.1, 1.4])
    yaws, tilts = np.radians([-100.0, 0.0, 35.0]), np.radians([-15.0, -50.0])
    sums = view_sums(pts - cam, np.ones((pts.shape[0], 1)), yaws, tilts, CAM)
    for p, yaw in enumerate(yaws):
        for t, tilt in enumerate(tilts):
            pose = CameraPose.from_pan_tilt(*cam, float(yaw), float(tilt))
            assert sums[p, t, 0] == pytest.approx(in_view(pose, CAM, pts).sum(), abs=2)


def test_rate_station_matches_brute_force_h() -> None:
    """Issue 5 items 1-2: H of pan/tilt views from the fast path equals the brute-force sum of
    (n_max - n)/n_max h2(IF P_V / 2) over the culled cells within 3 %."""
    truth, textured = synthetic_terrain(GRID, seed=4)
    emap = panorama_map(truth, textured, GRID, CAM, MastConfig(), (0.0, 0.0, 0.0))
    vis = VisibilityConfig()
    terrain = terrain_from_map(emap.z, emap.var, GRID, vis)
    cam = (1.2, -0.05, 1.5)
    yaws, tilts = np.radians([-90.0, -45.0]), np.radians([-30.0, -45.0])
    r = rate_station(terrain, cam, yaws, tilts, emap.n, emap.n_max, emap.interest, CAM, vis)
    iy, ix = np.nonzero(np.ones(GRID.shape, bool))
    pts = cell_points(terrain, iy, ix)
    for p, yaw in enumerate(yaws):
        for t, tilt in enumerate(tilts):
            sel = in_view(CameraPose.from_pan_tilt(*cam, float(yaw), float(tilt)), CAM, pts)
            pv = pv_reference(terrain, cam, iy[sel], ix[sel])
            bits, new = cell_values(pv, emap.n[iy[sel], ix[sel]], emap.n_max,
                                    emap.interest[iy[sel], ix[sel]], stereo_return=vis.stereo_return)
            assert r.info_bits[p, t] == pytest.approx(bits.sum(), rel=0.03)
            assert r.expected_new_cells[p, t] == pytest.approx(new.sum(), rel=0.03, abs=2.0)
    assert r.info_bits.max() > 10.0


def test_predicted_visibility_is_zero_outside_the_view() -> None:
    """§4: the P_V map handed to the map's miss recording is culled to the view."""
    truth, textured = synthetic_terrain(GRID, seed=5)
    emap = panorama_map(truth, textured, GRID, CAM, MastConfig(), (0.0, 0.0, 0.0))
    pose = CameraPose.from_pan_tilt(1.0, 0.0, 1.5, -math.pi / 2, -0.6)
    pv = predicted_visibility(emap, pose, CAM, VisibilityConfig())
    xs, ys = GRID.centers()
    assert pv[ys > 0.2].max() == 0.0  # behind the camera
    assert pv.max() > 0.5 and ((pv >= 0) & (pv <= 1)).all()


def test_motion_cost_eq9() -> None:
    """§3.3: zero for the same pose, per-axis weights, angles wrap."""
    cur = np.array([1.0, 2.0, math.pi - 0.01, 0.0, -0.5, 0.5])
    poses = np.array([cur, cur + [1, 0, 0, 0, 0, 0], cur + [0, 0, 0.02, 0, 0, 0]])
    d = motion_cost(poses, cur, CFG)
    assert d[0] == 0.0
    assert d[1] == pytest.approx(math.sqrt(CFG.a_xy))
    assert d[2] == pytest.approx(math.sqrt(CFG.a_yaw) * 0.02)  # wraps past pi


def test_localization_and_utility() -> None:
    """§3.5: sigma_loc grows with travel, a fiducial in range pulls it down; U = H - w_d d -
    w_l sigma."""
    s = localization_sigma(np.array([0.0, 2.0, 2.0]), 0.01, np.array([np.inf, np.inf, 1.0]), CFG)
    assert s[0] == pytest.approx(0.01) and s[1] > s[0] and s[2] < s[1]
    u = utility(np.array([100.0]), np.array([2.0]), np.array([0.01]), CFG)
    assert u[0] == pytest.approx(100.0 - CFG.w_motion * 2.0 - CFG.w_loc * 0.01)


def test_end_criterion() -> None:
    """§3.6: step limit, mapped fraction, best H below a threshold, else go on."""
    assert "step limit" in end_reason(20, 500.0, 0.2, CFG)
    assert "mapped" in end_reason(3, 500.0, 0.99, CFG)
    assert "bit" in end_reason(3, 1.0, 0.2, CFG)
    assert end_reason(3, 500.0, 0.2, CFG) is None


def test_nbv_config_validates() -> None:
    """Bad config is refused with file: key: reason."""
    with pytest.raises(ConfigError, match="nbv.visibility.rays_per_turn"):
        build(NbvConfig, {"visibility": {"rays_per_turn": 3}}, "fsw.toml", "nbv")
    with pytest.raises(ConfigError, match="nbv.tilts_deg"):
        build(NbvConfig, {"tilts_deg": "down"}, "fsw.toml", "nbv")
    assert build(NbvConfig, {"lifts_m": [0.1, 0.4]}, "x", "nbv").lifts_m == (0.1, 0.4)
