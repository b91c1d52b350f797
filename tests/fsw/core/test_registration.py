"""Registration of a view against the map (issue 13, item 2; docs/algorithm.md §5.1): a known
injected pose error is recovered; unconstrained directions stay at their prior; a view that
cannot be registered says why and is merged with an inflated covariance; bounded steps."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from fsw.core.geometry import CameraPose, MapGrid
from fsw.core.map.reference_frames import ReferenceFrames
from fsw.core.registration.registration import (
    Registration,
    RegistrationConfig,
    apply_correction,
    inflate,
    reference_cells,
    register_points,
    register_steps,
)
from fsw.core.registration.station_chain import StationFix, carried_prior

GRID = MapGrid(0.0, 0.0, 0.03, 120, 120)
CFG = RegistrationConfig()
PRIOR = np.diag([math.radians(0.5) ** 2] * 3 + [0.05**2] * 3)


def rough(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Sloped, undulating ground: constrains all six pose directions."""
    return 0.06 * np.sin(2 * np.pi * x / 0.9) + 0.05 * np.cos(2 * np.pi * y / 0.7) + 0.08 * x - 0.03 * y


def level(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return np.zeros(np.broadcast(x, y).shape)


def make_map(surface, sigma_m: float = 0.004):  # type: ignore[no-untyped-def]
    X, Y = GRID.centers()
    z = surface(X, Y)
    var = np.full(GRID.shape, sigma_m**2)
    n = np.ones(GRID.shape, np.int32)
    return z, var, n


def view_points(surface, true_pose: CameraPose, wrong_pose: CameraPose, box, noise_m: float = 0.004,  # type: ignore[no-untyped-def]
                n: int = 20000, seed: int = 0):
    """Points of the surface in ``box`` as a camera at ``true_pose`` sees them, put into the
    world with ``wrong_pose`` (the view's erroneous pose), with stereo noise."""
    rng = np.random.default_rng(seed)
    x = rng.uniform(box[0], box[1], n)
    y = rng.uniform(box[2], box[3], n)
    p = np.column_stack([x, y, surface(x, y)])
    pc = true_pose.world_to_camera(p) + rng.normal(0.0, noise_m, (n, 3))
    cov = np.broadcast_to(np.eye(3) * noise_m**2, (n, 3, 3)).copy()
    return wrong_pose.camera_to_world(pc), cov


def looking_down_x() -> CameraPose:
    fwd = np.array([math.cos(-0.6), 0.0, math.sin(-0.6)])
    right = np.array([0.0, -1.0, 0.0])
    return CameraPose(np.column_stack([right, np.cross(fwd, right), fwd]), np.array([0.2, 1.8, 1.5]))


def with_error(pose: CameraPose, d: np.ndarray) -> CameraPose:
    """The pose a view would carry if its true pose is ``apply_correction(it, d)``."""
    from fsw.core.localization.localization import so3_exp

    return CameraPose(so3_exp(-d[:3]) @ pose.R, pose.t - d[3:])


def test_recovers_a_known_injected_pose_error_on_rough_ground() -> None:
    """Roll 0.4, pitch -0.3, yaw 0.25 deg, x 2 cm, y -1.5 cm, z 3 cm injected: recovered to
    0.05 deg and 5 mm on ground whose slopes constrain all six directions."""
    d_err = np.r_[np.radians([0.4, -0.3, 0.25]), 0.02, -0.015, 0.03]
    true = looking_down_x()
    wrong = with_error(true, d_err)
    z, var, n = make_map(rough)
    pts, cov = view_points(rough, true, wrong, (1.0, 3.2, 0.6, 3.0))
    reg = register_points(pts, cov, wrong, PRIOR, GRID, z, var, reference_cells(z, var, n, CFG), CFG)
    assert reg.status == "registered", reg.reason
    np.testing.assert_allclose(np.degrees(reg.correction[:3]), np.degrees(d_err[:3]), atol=0.05)
    np.testing.assert_allclose(reg.correction[3:], d_err[3:], atol=0.005)
    fixed = apply_correction(wrong, reg.correction)
    assert np.linalg.norm(fixed.t - true.t) < 0.006
    assert set(reg.summary()["constrained"]) >= {"R", "P", "z"}
    sd = np.sqrt(np.diag(reg.cov))
    assert np.all(sd[:3] < math.radians(0.5)) and np.all(sd[3:] < 0.05)  # better than the prior
    assert reg.residual_sigma < 2.0


def test_level_ground_fixes_height_and_tilt_only() -> None:
    """On level ground x, y and yaw are not observable: they stay at the prior (no
    correction, not flagged constrained); height, roll and pitch are recovered."""
    d_err = np.r_[np.radians([-0.3, 0.35, 0.2]), 0.03, 0.02, -0.025]
    true = looking_down_x()
    wrong = with_error(true, d_err)
    z, var, n = make_map(level)
    pts, cov = view_points(level, true, wrong, (1.0, 3.2, 0.6, 3.0))
    reg = register_points(pts, cov, wrong, PRIOR, GRID, z, var, reference_cells(z, var, n, CFG), CFG)
    assert reg.status == "registered", reg.reason
    fixed = apply_correction(wrong, reg.correction)
    # the surface normal (and so roll and pitch) and the height are right again
    np.testing.assert_allclose(fixed.R[2], true.R[2], atol=math.radians(0.05))
    assert abs(reg.correction[2]) < math.radians(0.02) and np.hypot(*reg.correction[3:5]) < 0.002
    c = reg.summary()["constrained"]
    assert "x" not in c and "y" not in c and "Y" not in c


def test_too_little_overlap_and_empty_map_are_reported() -> None:
    true = looking_down_x()
    z, var, n = make_map(rough)
    n[:, :] = 0  # nothing mapped: the view is the map's reference
    pts, cov = view_points(rough, true, true, (1.0, 3.2, 0.6, 3.0), n=2000)
    ref = reference_cells(z, var, n, CFG)
    assert register_points(pts, cov, true, PRIOR, GRID, z, var, ref, CFG).status == "reference"
    n[:, :] = 1
    n[:, 40:] = 0  # mapped only where the view barely reaches
    var[:, :40] = 0.05**2  # ... and too poorly to be a reference
    var[:5, :5] = 0.001**2
    reg = register_points(pts, cov, true, PRIOR, GRID, z, var, reference_cells(z, var, n, CFG), CFG)
    assert reg.status == "unregistered" and "overlap" in reg.reason
    assert np.all(reg.correction == 0)
    big = inflate(PRIOR, CFG)
    assert np.all(np.diag(big) > np.diag(PRIOR))
    assert math.sqrt(big[0, 0] - PRIOR[0, 0]) == pytest.approx(math.radians(CFG.inflate_rot_deg))


def test_ill_conditioned_overlap_is_refused() -> None:
    """Overlap on a strip along the viewing direction: roll about that strip and height are
    one combination; the normal matrix is singular there and the view is not registered."""
    true = looking_down_x()
    z, var, n = make_map(level)
    pts, cov = view_points(level, true, true, (1.0, 3.2, 1.79, 1.81), n=5000)
    reg = register_points(pts, cov, true, PRIOR, GRID, z, var, reference_cells(z, var, n, CFG), CFG)
    assert reg.status == "unregistered" and "ill-conditioned" in reg.reason


def test_registration_runs_in_bounded_steps_and_rejects_garbage() -> None:
    """One Gauss-Newton iteration per step (slack-job slices: the fit, then each half of the
    consistency check); NaN points are ignored."""
    d_err = np.r_[np.radians([0.2, -0.2, 0.0]), 0.0, 0.0, 0.02]
    true = looking_down_x()
    wrong = with_error(true, d_err)
    z, var, n = make_map(rough)
    pts, cov = view_points(rough, true, wrong, (1.0, 3.2, 0.6, 3.0))
    pts[::7] = np.nan
    gen = register_steps(pts, cov, wrong, PRIOR, GRID, z, var, reference_cells(z, var, n, CFG), CFG)
    steps = 0
    try:
        while True:
            next(gen)
            steps += 1
    except StopIteration as stop:
        reg: Registration = stop.value
    assert 2 <= steps <= 3 * CFG.iterations + 1 and reg.status == "registered"
    assert reg.split_chi2 < 22.46  # chi-square 6 dof, 0.1 %
    assert abs(reg.correction[5] - 0.02) < 0.004


def _odometry_error(pose: CameraPose, dyaw: float, shift: np.ndarray, pivot: np.ndarray) -> CameraPose:
    """The pose dead reckoning reports when its world frame is turned by ``-dyaw`` about
    ``pivot`` and shifted by ``-shift`` (a rigid drift error common to every pose)."""
    from fsw.core.localization.localization import so3_exp

    Rz = so3_exp(np.r_[0.0, 0.0, -dyaw])
    return CameraPose(Rz @ pose.R, Rz @ (pose.t - pivot) + pivot - shift)


def test_carried_prior_undoes_a_rigid_drift_at_the_next_station() -> None:
    """Odometry drift is a rigid error of the world frame: once a station has found it, the
    next station (2.5 m on, turned) starts from it, exact up to what the drive added; roll and
    pitch are not carried (the attitude sensor measures them afresh)."""
    dyaw, shift, pivot = math.radians(3.0), np.array([0.08, -0.12, 0.01]), np.array([0.3, -0.2, 0.0])
    true1 = looking_down_x()
    true2 = CameraPose(true1.R @ np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]),
                       true1.t + np.array([2.5, 0.4, 0.02]))
    est1, est2 = (_odometry_error(p, dyaw, shift, pivot) for p in (true1, true2))
    # station 1's registration: the correction that takes est1 onto true1 (about est1's centre)
    from fsw.core.localization.localization import so3_log

    d1 = np.r_[so3_log(true1.R @ est1.R.T), true1.t - est1.t]
    S1 = np.diag([math.radians(0.2) ** 2] * 2 + [math.radians(2.0) ** 2] + [0.05**2] * 3)
    S2 = S1 + np.diag([0.0, 0.0, math.radians(1.0) ** 2, 0.03**2, 0.03**2, 0.01**2])  # the drive since
    C1 = np.diag([math.radians(0.05) ** 2] * 3 + [0.004**2] * 3)
    fix = StationFix(est1.t.copy(), d1, C1, S1, np.zeros((6, 6)))
    d0, cov = carried_prior(est2, S2, fix)
    assert d0[0] == d0[1] == 0.0
    carried = apply_correction(est2, d0)
    assert np.linalg.norm(carried.t - true2.t) < 1e-9
    assert math.degrees(float(np.linalg.norm(so3_log(carried.R @ true2.R.T)))) < 1e-7
    # without the carry the view would start 3 deg and 4 cm off
    assert np.linalg.norm(est2.t - true2.t) > 0.04
    assert math.degrees(float(np.linalg.norm(so3_log(est2.R @ true2.R.T)))) == pytest.approx(3.0)
    # covariance: symmetric positive definite; roll/pitch keep the view's own prior; the dead
    # reckoned block is the drive's growth plus the carried correction's error with its lever
    np.testing.assert_allclose(cov, cov.T)
    assert np.linalg.eigvalsh(cov).min() > 0
    np.testing.assert_allclose(np.diag(cov)[:2], np.diag(S2)[:2])
    lever = np.linalg.norm((est2.t - est1.t)[:2])
    grown_xy = 0.03**2 + 0.004**2
    assert np.diag(cov)[3:5].max() <= grown_xy + (math.radians(0.05) * lever) ** 2 + 1e-12
    assert np.diag(cov)[3:5].min() >= grown_xy
    assert np.diag(cov)[2] == pytest.approx(math.radians(1.0) ** 2 + math.radians(0.05) ** 2)
    # far tighter than the dead-reckoning covariance it replaces
    assert np.all(np.diag(cov)[2:5] < 0.5 * np.diag(S2)[2:5])


def test_carried_prior_clips_a_shrinking_odometry_covariance() -> None:
    """A pose covariance that shrank since the last station (e.g. a reset) gives no negative
    growth: the carried block stays positive semidefinite."""
    pose = looking_down_x()
    S1 = np.diag([1e-4] * 6)
    fix = StationFix(pose.t.copy(), np.zeros(6), np.diag([1e-8] * 6), S1, np.zeros((6, 6)))
    _, cov = carried_prior(pose, 0.25 * S1, fix)
    assert np.linalg.eigvalsh(cov).min() >= -1e-15
    assert np.all(np.diag(cov)[2:] <= 1e-8 + 1e-15)


def test_a_view_whose_halves_disagree_is_not_registered_into_the_false_minimum() -> None:
    """An injected false minimum: the far half of the reference area was placed 8 cm off in y
    (by another view's pose error), so the view's two halves align to different places. The
    fit alone settles between them with a small stated sigma; the split-half check sees the
    halves disagree far beyond their covariances in six directions: the view is refused (then
    merged with its covariance inflated) or registered in height and tilt only, yaw, x and y
    kept at the prior, and what it does correct is within its stated sigma of the truth (the
    true pose is the prior here), never silently. The same view on a consistent map passes."""
    true = looking_down_x()
    X, Y = GRID.centers()
    z_ok = rough(X, Y)
    z_bad = np.where(X < 2.2, rough(X, Y), rough(X, Y - 0.08))
    var, n = np.full(GRID.shape, 0.004**2), np.ones(GRID.shape, np.int32)
    pts, cov = view_points(rough, true, true, (1.0, 3.4, 1.2, 2.4))
    good = register_points(pts, cov, true, PRIOR, GRID, z_ok, var, reference_cells(z_ok, var, n, CFG), CFG)
    assert good.status == "registered" and good.split_chi2 < 22.46 and good.reason == ""
    bad = register_points(pts, cov, true, PRIOR, GRID, z_bad, var, reference_cells(z_bad, var, n, CFG), CFG)
    assert "halves disagree" in bad.reason and bad.summary()["split_chi2"] == bad.split_chi2
    if bad.status == "unregistered":
        assert np.all(bad.correction == 0)
    else:
        assert bad.status == "registered" and bad.reason.startswith("height and tilt only"), bad.reason
        assert np.all(bad.correction[2:5] == 0)  # yaw, x, y: the false minimum not taken
        fitted = [0, 1, 5]
        assert np.all(np.abs(bad.correction[fitted]) <= 2 * np.sqrt(np.diag(bad.cov)[fitted]))
    off = dataclasses.replace(CFG, split_alpha=0.0)  # the check off: the compromise is accepted
    blind = register_points(pts, cov, true, PRIOR, GRID, z_bad, var, reference_cells(z_bad, var, n, off), off)
    assert blind.status == "registered" and math.isnan(blind.split_chi2)
    assert abs(blind.correction[4]) > 0.005  # pulled off in y by the false half: the check keeps y


def test_the_reference_cells_own_pose_error_joins_the_covariance() -> None:
    """The cells a view aligns to are only as well placed as the view that mapped them: with
    that view's pose error 0.2 mm the correction's covariance is the fit's; with 3 cm and
    0.3 deg it grows to about that (rough ground: the fit follows the cells in all six
    directions), and the part is reported (``ref_cov``, ``ref_sigma``)."""
    true = looking_down_x()
    z, var, n = make_map(rough)
    pts, cov = view_points(rough, true, true, (1.0, 3.2, 0.6, 3.0))
    ref = reference_cells(z, var, n, CFG)
    plain = register_points(pts, cov, true, PRIOR, GRID, z, var, ref, CFG)
    sd = {}
    for name, s_pos, s_rot in (("tiny", 0.0002, 0.001), ("big", 0.03, 0.3)):
        frames = ReferenceFrames(GRID.shape)
        X, Y = GRID.centers()
        cells = np.arange(GRID.nx * GRID.ny)
        src_cov = np.diag([math.radians(s_rot) ** 2] * 3 + [s_pos**2] * 3)
        frames.add(cells, np.column_stack([X.ravel(), Y.ravel(), z.ravel()]), np.array([0.0, 1.8, 1.5]), src_cov)
        reg = register_points(pts, cov, true, PRIOR, GRID, z, var, ref, CFG, frames)
        assert reg.status == "registered", reg.reason
        np.testing.assert_allclose(reg.cov - reg.ref_cov, plain.cov, rtol=1e-9, atol=1e-14)
        sd[name] = np.sqrt(np.diag(reg.cov))
        assert reg.summary()["ref_sigma"][3] == pytest.approx(math.sqrt(reg.ref_cov[3, 3]), abs=1e-6)
    np.testing.assert_allclose(sd["tiny"], np.sqrt(np.diag(plain.cov)), rtol=0.05)
    assert np.all(sd["big"] > 2 * sd["tiny"])
    assert np.all(sd["big"][3:] > 0.6 * 0.03)  # the position error of the reference, mostly followed


def ridges(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Short ridges across y on a gentle slope: y is observable, height and tilt too."""
    return 0.01 * np.sin(2 * np.pi * y / 0.3) + 0.02 * np.sin(2 * np.pi * x / 1.1) + 0.03 * x


def test_halves_that_disagree_only_horizontally_keep_height_and_tilt() -> None:
    """The far half of the reference 8 cm off in y along ridges of zero mean: the halves
    disagree in y, not in height and tilt. The view is registered in height, roll and pitch
    only; yaw, x and y stay at the prior with the prior's sigma (never a confident wrong y),
    and the record says so. On the consistent map all six directions are registered."""
    true = looking_down_x()
    X, Y = GRID.centers()
    var, n = np.full(GRID.shape, 0.004**2), np.ones(GRID.shape, np.int32)
    pts, cov = view_points(ridges, true, true, (1.0, 3.4, 1.2, 2.4))
    z_ok = ridges(X, Y)
    ok = register_points(pts, cov, true, PRIOR, GRID, z_ok, var, reference_cells(z_ok, var, n, CFG), CFG)
    assert ok.status == "registered" and ok.reason == "" and "y" in ok.summary()["constrained"]
    z_bad = np.where(X < 2.2, ridges(X, Y), ridges(X, Y - 0.08))
    reg = register_points(pts, cov, true, PRIOR, GRID, z_bad, var, reference_cells(z_bad, var, n, CFG), CFG)
    assert reg.status == "registered" and reg.reason.startswith("height and tilt only"), reg.reason
    assert "halves disagree" in reg.reason and reg.split_chi2 < 16.27  # chi-square 3 dof, 0.1 %
    assert np.all(reg.correction[2:5] == 0.0)  # yaw, x, y: the prior
    np.testing.assert_allclose(np.diag(reg.cov)[2:5], np.diag(PRIOR)[2:5], rtol=1e-6)
    assert set(reg.summary()["constrained"]) <= {"R", "P", "z"}
    assert abs(reg.correction[5]) < 0.005 and abs(reg.correction[1]) < math.radians(0.05)
    # roll absorbs what y held at the prior may be off by: its sigma says so
    assert abs(reg.correction[0]) < 2 * math.sqrt(reg.cov[0, 0])


def test_a_flat_cost_in_yaw_on_level_ground_keeps_the_prior_sigma() -> None:
    """Issue 27 (cliff-team seed 1): level ground with only millimetre relief at the cell scale
    (the map's own), a view 4 deg off in yaw and 3 cm in x and y with a prior that says so. The
    normal matrix takes the relief's gradients at face value and claims yaw and x, y to a
    fraction of the prior, while the cost is as low at the truth as at the fit: the claimed
    sigma would be several times too small. The curvature check sees the flat cost and drops
    that information (yaw keeps about the prior's sigma), so the view's error stays within 2
    sigma; height and tilt are still registered. With the check off the old over-confident fit comes back."""
    rng = np.random.default_rng(3)
    field = rng.normal(0.0, 0.002, GRID.shape)  # relief at cell centres: independent per cell
    from scipy.ndimage import map_coordinates

    def relief(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        cx, cy = (np.asarray(x) - GRID.x0) / GRID.cell - 0.5, (np.asarray(y) - GRID.y0) / GRID.cell - 0.5
        return np.asarray(map_coordinates(field, [cy.ravel(), cx.ravel()], order=1, mode="nearest")).reshape(cx.shape)

    d_err = np.r_[np.radians([0.1, -0.1, 4.0]), 0.03, -0.03, 0.01]
    prior = np.diag(np.r_[np.radians([0.15, 0.15, 4.5]) ** 2, 0.035**2, 0.035**2, 0.015**2])
    true = looking_down_x()
    wrong = with_error(true, d_err)
    z, var, n = make_map(relief, 0.003)
    pts, cov = view_points(relief, true, wrong, (1.0, 3.2, 0.6, 3.0), noise_m=0.002)
    ref = reference_cells(z, var, n, CFG)

    def miss(r: Registration) -> np.ndarray:  # the remaining error of yaw, x, y in its sigmas
        return np.abs(d_err[2:5] - r.correction[2:5]) / np.sqrt(np.diag(r.cov)[2:5])

    blind = register_points(pts, cov, wrong, prior, GRID, z, var, ref, dataclasses.replace(CFG, curvature_sigma=0.0))
    assert blind.status == "registered" and blind.reason == ""
    assert miss(blind).max() > 3.0  # the old fit: confident and wrong
    reg = register_points(pts, cov, wrong, prior, GRID, z, var, ref, CFG)
    assert reg.status == "registered" and reg.reason.startswith("flat cost"), reg.reason
    assert miss(reg).max() < 2.0 and np.sqrt(reg.cov[2, 2]) > 0.5 * np.sqrt(prior[2, 2])
    assert "Y" not in reg.summary()["constrained"]
    fixed = apply_correction(wrong, reg.correction)
    np.testing.assert_allclose(fixed.R[2], true.R[2], atol=math.radians(0.05))  # tilt still registered
