"""Stereo: SGBM disparity, validity filters and the point covariance (docs/algorithm.md §4, §1.2)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from perception_planes import render_plane, texture
from step_count import count_steps

from fsw.core.geometry import CameraConfig, CameraPose
from fsw.core.localization.localization import propagate_point_covariance
from fsw.core.stereo import stereo_quality as q
from fsw.core.stereo.stereo import StereoConfig, StereoMatcher, depth_sigma_m, stereo_covariance
from fsw.framework.params import ConfigError, build

CAM = CameraConfig(width_px=320, height_px=240)


@pytest.fixture(scope="module")
def plane_pair() -> tuple[CameraPose, np.ndarray, np.ndarray]:
    pose = CameraPose.from_pan_tilt(0.0, 0.0, 1.3, 0.0, math.radians(-35.0))
    left, right = render_plane(CAM, pose, texture(3), 0.006, flat_box=(2.0, 2.6, -0.3, 0.3))
    return pose, left, right


def test_plane_elevation_error_matches_predicted_sigma(plane_pair) -> None:
    """Issue 4, item 1: points of a textured plane carry a sigma that matches their error."""
    pose, left, right = plane_pair
    sp = StereoMatcher(StereoConfig(num_disparities_px=64), CAM).points(left, right)
    assert len(sp) > 20000
    pw, P = propagate_point_covariance(pose, None, sp.xyz_c, sp.cov_c)
    err = pw[:, 2]  # the plane is z = 0
    sig = np.sqrt(P[:, 2, 2])
    assert np.sqrt(np.mean(err**2)) < 0.02
    ratio = np.sqrt(np.mean(err**2)) / np.sqrt(np.mean(sig**2))
    assert 0.5 <= ratio <= 1.5, ratio  # honest to within a factor (calibrated end to end)
    assert np.mean(np.abs(err) <= 2 * sig) >= 0.9


def test_textureless_patch_gives_no_points(plane_pair) -> None:
    """Issue 4, done-when 4 (unit level): a flat-albedo patch yields no points, not garbage."""
    pose, left, right = plane_pair
    sp = StereoMatcher(StereoConfig(num_disparities_px=64), CAM).points(left, right)
    pw, _ = propagate_point_covariance(pose, None, sp.xyz_c, sp.cov_c)
    # 10 cm in from the patch's edges: the 7 px correlation window (issue 14) spans up to
    # 10 cm of this grazing plane at the patch's far edge, and a window that reaches the
    # textured rim matches the rim, correctly
    inner = (pw[:, 0] > 2.10) & (pw[:, 0] < 2.50) & (np.abs(pw[:, 1]) < 0.20)
    assert inner.sum() == 0
    outside = (pw[:, 0] > 2.8) & (pw[:, 0] < 3.4) & (np.abs(pw[:, 1]) < 0.24)
    assert outside.sum() > 500  # the texture around it still matches


def test_covariance_is_first_order_propagation() -> None:
    """§1.2: the covariance equals J diag(su^2, sv^2, sd^2) J^T, depth part Z^2 sd / (f B)."""
    f, B, sp, sd = 500.0, 0.15, 0.3, 0.2
    rng = np.random.default_rng(0)
    du, dv, d = rng.uniform(-300, 300, 50), rng.uniform(-200, 200, 50), rng.uniform(5, 100, 50)
    cov = stereo_covariance(du, dv, d, f, B, sp, sd)

    def point(a: np.ndarray) -> np.ndarray:
        return np.array([B * a[0] / a[2], B * a[1] / a[2], f * B / a[2]])

    for i in range(5):
        a = np.array([du[i], dv[i], d[i]])
        J = np.column_stack([(point(a + e) - point(a - e)) / 2e-6 for e in np.eye(3) * 1e-6])
        ref = J @ np.diag([sp**2, sp**2, sd**2]) @ J.T
        np.testing.assert_allclose(cov[i], ref, rtol=1e-5, atol=1e-12)
        z = f * B / d[i]
        assert math.isclose(math.sqrt(cov[i, 2, 2]), z**2 * sd / (f * B), rel_tol=1e-9)
    cam = CameraConfig()
    assert math.isclose(float(depth_sigma_m(3.0, cam, 0.2)),
                        9.0 * 0.2 / (cam.focal_px * cam.baseline_m))


def test_bad_images_are_refused_with_a_clear_error() -> None:
    """Bad input -> clear error: wrong size, dtype or a missing image."""
    m = StereoMatcher(StereoConfig(num_disparities_px=64), CAM)
    good = np.zeros((240, 320), np.uint8)
    with pytest.raises(ValueError, match="uint8 of shape"):
        m.points(good, np.zeros((240, 321), np.uint8))
    with pytest.raises(ValueError, match="left image"):
        m.points(good.astype(np.float32), good)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="right image"):
        m.points(good, None)  # type: ignore[arg-type]


def test_stereo_config_validation() -> None:
    """Config: SGBM constraints are refused with file: key: reason."""
    with pytest.raises(ConfigError, match="multiple of 16"):
        build(StereoConfig, {"num_disparities_px": 100}, "fsw.toml", "stereo")
    with pytest.raises(ConfigError, match="odd"):
        build(StereoConfig, {"block_size_px": 4}, "fsw.toml", "stereo")
    with pytest.raises(ConfigError, match="stereo.mode"):
        build(StereoConfig, {"mode": "bm"}, "fsw.toml", "stereo")
    assert build(StereoConfig, {}, "x", "stereo") == StereoConfig()


def test_triangulation_slices_are_bounded_by_points_and_change_nothing(plane_pair) -> None:
    """Issue 15 (slices <= 20 ms): the triangulation yields every ``step_points`` points, in
    row-major order; the points are those of one whole-image pass, to the bit."""
    _, left, right = plane_pair
    m = StereoMatcher(StereoConfig(num_disparities_px=64), CAM)
    dm = m.match(left, right)
    whole = m.triangulate(dm.disparity_px, sigma_px=dm.sigma_px)
    n = len(whole)
    assert n > 20000
    for step in (997, 5000, n, 10 * n):
        slices, pts = count_steps(m.triangulate_steps(dm.disparity_px, sigma_px=dm.sigma_px, step_points=step))
        assert slices == -(-n // step)  # ceil: no slice holds more than step points
        for f in ("xyz_c", "cov_c", "uv", "disparity_px", "valid"):
            assert np.array_equal(getattr(pts, f), getattr(whole, f)), f
    with pytest.raises(ValueError, match="step_points"):
        next(m.triangulate_steps(dm.disparity_px, step_points=0))


def test_grazing_term_follows_the_disparity_gradient() -> None:
    """docs/algorithm.md §1.2, grazing incidence: the disparity's slope over the window (a plane's
    ``B tan(theta) / Z``) measured through noise and holes, and its term in the per-pixel sigma."""
    rng = np.random.default_rng(0)
    vv, uu = np.mgrid[0:60, 0:80].astype(np.float64)
    plane = 20.0 + 0.3 * uu + 0.1 * vv + rng.normal(0.0, 0.05, uu.shape)
    plane[20:25, 30:35] = np.nan  # a hole: its neighbours still fit a plane
    g = q.disparity_gradient(plane, 5)
    inner = np.isfinite(plane)
    inner[:3], inner[-3:], inner[:, :3], inner[:, -3:] = False, False, False, False
    assert np.median(np.abs(g[inner] - np.hypot(0.3, 0.1))) < 0.01
    flat = q.disparity_gradient(np.full((30, 30), 12.0) + rng.normal(0.0, 0.05, (30, 30)), 5)
    assert np.median(flat) < 0.03  # fronto-parallel: no span
    assert (q.disparity_gradient(np.full((10, 10), np.nan), 5) == 0.0).all()
    ls, spread = np.full((1, 3), 0.1, np.float32), np.zeros((1, 3), np.float32)
    span = np.array([[0.0, 1.0, 4.0]])
    s = q.disparity_sigma(ls, spread, 0.11, 1.0, 6.0, span, 0.29)
    base = math.hypot(0.11, 0.1)
    assert s[0, 0] == pytest.approx(base) and s[0, 2] == pytest.approx(math.hypot(base, 0.29 * 4.0))
    assert (np.diff(s[0]) > 0).all()


def test_local_spread_of_a_plane_beside_a_mismatched_patch_is_zero_not_nan() -> None:
    """A plane (constant disparity: spread exactly 0) beside a patch of wild disparities: OpenCV's
    running box sums leave a residue like -2e-10 in the plane's windows; the spread is 0 there,
    never the NaN (and the "invalid value in sqrt" warning) its square root gave."""
    rng = np.random.default_rng(0)
    d = np.full((120, 160), 20.0)
    d[:60, :80] += rng.uniform(-200.0, 200.0, (60, 80))
    d[rng.random(d.shape) < 0.05] = np.nan  # holes, as SGBM leaves
    with np.errstate(invalid="raise"):
        s = q.local_spread(d, 9)
    assert np.isfinite(s).all() and (s >= 0.0).all()
    assert (s[80:, 100:] == 0.0).all()  # the plane, away from the patch
    assert np.median(s[10:50, 10:70]) > 10.0  # the patch's own roughness is kept
