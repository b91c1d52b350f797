"""The registration's correction fed back into the rover pose (fsw.core.localization.nav_fix, the station
chain's bookkeeping, the odometry's covariance after a fix; issue 13: odometry drift put a wheel
on ground the map did not know)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fsw.core.geometry import CameraPose, camera_pose_from_rover
from fsw.core.localization.localization import so3_exp
from fsw.core.localization.nav_fix import NavFix, apply_to_body, residual_correction
from fsw.core.localization.odometry import Odometry, drift_sigma
from fsw.core.motion import wheel_kinematics as wk
from fsw.core.motion.motion_profile import MotionConfig
from fsw.core.registration.registration import Registration, RegistrationConfig
from fsw.core.registration.station_chain import StationChain
from fsw.settings import load_settings

MAST = load_settings().mast
JOINTS = (math.radians(-70.0), math.radians(-35.0), 0.4)
ATT = (math.radians(3.0), math.radians(-4.0))


def _camera(body: tuple[float, float, float], z: float = 0.3) -> CameraPose:
    return camera_pose_from_rover(body, JOINTS, MAST, z, ATT)


def test_fixed_body_pose_puts_the_camera_where_the_registration_did() -> None:
    """A correction found on the camera (yaw about its centre, then a shift) moved onto the
    body: the camera computed from the corrected body is the corrected camera, roll and pitch
    from the sensor unchanged."""
    body = (2.0, -1.0, math.radians(30.0))
    cam = _camera(body)
    d = np.r_[0.0, 0.0, math.radians(6.5), 0.21, -0.31, 0.04]
    fix = NavFix.from_correction(1, 0.0, cam.t, d, np.diag([1e-6, 1e-6, 1e-4, 4e-4, 4e-4, 1e-4]))
    new, _ = apply_to_body(body, fix)
    got = _camera(new, 0.3 + fix.dt[2])
    np.testing.assert_allclose(got.t, cam.t + d[3:], atol=1e-9)
    np.testing.assert_allclose(got.R, so3_exp(d[:3]) @ cam.R, atol=1e-9)


def test_body_covariance_carries_the_yaw_sigma_by_its_lever() -> None:
    """Yaw uncertainty about a camera centre 1 m ahead of the body is 1 m x sigma_yaw of body
    position across that lever; none along it."""
    s_yaw = math.radians(2.0)
    cov6 = np.diag([0.0, 0.0, s_yaw**2, 0.0, 0.0, 0.0])
    fix = NavFix.from_correction(1, 0.0, np.array([1.0, 0.0, 0.5]), np.zeros(6), cov6)
    _, cov = apply_to_body((0.0, 0.0, 0.0), fix)
    assert cov[0, 0] == pytest.approx(0.0, abs=1e-15)
    assert math.sqrt(cov[1, 1]) == pytest.approx(1.0 * s_yaw)
    assert math.sqrt(cov[2, 2]) == pytest.approx(s_yaw)


def test_residual_is_the_roll_and_pitch_left_after_the_yaw() -> None:
    d = np.r_[math.radians(0.4), math.radians(-0.3), math.radians(5.0), 0.1, 0.2, 0.03]
    res = residual_correction(d)
    assert not res[3:].any()
    np.testing.assert_allclose(so3_exp(res[:3]) @ so3_exp(np.r_[0.0, 0.0, d[2]]), so3_exp(d[:3]), atol=1e-12)
    assert abs(res[2]) < 1e-3 * abs(d[2])


def test_odometry_grows_from_the_fix_covariance() -> None:
    cfg = MotionConfig()
    odo = Odometry(0.1, np.eye(3, 8))
    odo.path_m, odo.turned_rad = 6.0, 1.0  # a long drive: a large sigma
    before = odo.covariance(cfg)
    base = np.diag([0.01**2, 0.02**2, math.radians(0.5) ** 2])
    odo.correct((1.0, 2.0, 0.3), base)
    np.testing.assert_allclose(odo.covariance(cfg), base)
    assert odo.covariance(cfg)[0, 0] < before[0, 0]
    odo.path_m += 1.0  # one more metre: its growth, and the fix's heading sigma over that metre
    grown = odo.covariance(cfg)[0, 0] - base[0, 0]
    assert grown == pytest.approx((cfg.odo_sigma_per_m * 1.0 + math.radians(0.5) * 1.0) ** 2)
    assert odo.state()["base_cov"] == base.tolist()


def test_heading_error_bends_the_position_sigma_quadratically() -> None:
    """Driving straight with a heading sigma growing k per metre, the position sigma is
    k L + k L^2 / 2 (the integrated heading error), in the odometry and in the geofence's
    prediction alike."""
    cfg = MotionConfig()
    k = cfg.odo_sigma_per_m
    rover = load_settings().rover
    odo = Odometry(0.1, wk.body_motion_matrix(wk.wheel_positions(rover)))
    odo.update(np.zeros(4), np.zeros(4))
    for i in range(1, 301):  # 3 m in 1 cm steps, wheels straight
        odo.update(np.full(4, i * 0.01 / 0.1), np.zeros(4))
    L = odo.path_m
    assert abs(L - 3.0) < 1e-6
    assert math.sqrt(odo.covariance(cfg)[0, 0]) == pytest.approx(k * L + k * L * L / 2, rel=0.01)
    s = np.linspace(0.0, 3.0, 301)
    assert drift_sigma(0.0, 0.0, s, np.zeros_like(s), cfg)[-1] == pytest.approx(k * L + k * L * L / 2, rel=0.01)


def _registered(chain: StationChain, pose: CameraPose, nav_id: int, d: np.ndarray,
                cov: float = 1e-6) -> NavFix | None:
    """One registered view whose total correction is ``d``; the fix it feeds back, if any."""
    cfg = RegistrationConfig()
    vp = chain.prior(pose, np.eye(6) * 1e-4, nav_id, cfg)
    reg = Registration("registered", correction=d - vp.d0, cov=np.eye(6) * cov)
    _, _, fix = chain.registered(pose, np.eye(6) * 1e-4, nav_id, 0.0, vp, reg, cfg)
    return fix


def _station(chain: StationChain, pose: CameraPose, nav_id: int, d: np.ndarray) -> NavFix | None:
    """Two views from one station that agree on ``d``: the second confirms it."""
    assert _registered(chain, pose, nav_id, d) is None  # one view alone moves nothing
    return _registered(chain, pose, nav_id, d)


def test_one_view_alone_never_moves_the_rover_and_a_disagreeing_second_does_not_either() -> None:
    """A false minimum (terrain seed 6: 11 deg of yaw from one weakly constrained view) must
    not reach the rover's pose: the fix needs a second view from the station that agrees."""
    chain = StationChain()
    a = _camera((0.0, 0.0, 0.0))
    wrong = np.r_[0.0, 0.0, math.radians(-11.0), 0.0, 0.22, 0.0]
    assert _registered(chain, a, 0, wrong, cov=(math.radians(1.5)) ** 2) is None
    # the next view from the station finds the truth (no correction): 11 deg from the first
    assert _registered(chain, a, 0, np.zeros(6), cov=(math.radians(1.5)) ** 2) is None
    # two that agree: fed back
    fix = _registered(chain, a, 0, np.r_[0.0, 0.0, 1e-4, 0.0, 0.0, 0.0], cov=(math.radians(1.5)) ** 2)
    assert fix is not None and fix.fix_id == 1


def test_a_fed_back_correction_is_not_carried_twice() -> None:
    """Station A finds a drift and feeds it back (fix 1). A view from a new station whose pose
    holds fix 1 starts from no correction (the odometry has it); one whose pose does not hold
    it yet (the frame it was found on) carries it as before."""
    cfg = RegistrationConfig()
    chain = StationChain()
    a = _camera((0.0, 0.0, 0.0))
    d = np.r_[0.0, 0.0, math.radians(4.0), 0.12, -0.05, 0.02]
    fix = _station(chain, a, 0, d)
    assert fix is not None and fix.fix_id == 1 and fix.base_id == 0
    b = _camera((1.0, 0.2, 0.1))
    held = chain.prior(b, np.eye(6) * 1e-4, 1, cfg)
    assert not held.same_station and not held.d0.any()
    not_yet = chain.prior(b, np.eye(6) * 1e-4, 0, cfg)
    assert not_yet.d0[2] == pytest.approx(d[2])


def test_same_station_after_the_fix_starts_from_the_roll_pitch_residual() -> None:
    cfg = RegistrationConfig()
    chain = StationChain()
    a = _camera((0.0, 0.0, 0.0))
    d = np.r_[math.radians(0.3), math.radians(-0.2), math.radians(3.0), 0.10, 0.05, 0.02]
    assert _station(chain, a, 0, d) is not None
    # the same station seen through the corrected odometry: its centre moved by dt
    moved = CameraPose(so3_exp(np.r_[0.0, 0.0, d[2]]) @ a.R, a.t + d[3:])
    vp = chain.prior(moved, np.eye(6) * 1e-4, 1, cfg)
    assert vp.same_station
    np.testing.assert_allclose(so3_exp(vp.d0[:3]) @ moved.R, so3_exp(d[:3]) @ a.R, atol=1e-12)
    assert not vp.d0[3:].any()
    # through the old frame (pose not yet corrected), the same station starts from the whole correction
    old = chain.prior(a, np.eye(6) * 1e-4, 0, cfg)
    assert old.same_station and np.allclose(old.d0, d)


def test_station_chain_survives_a_checkpoint() -> None:
    chain = StationChain()
    chain.reference(np.eye(6) * 2e-4)
    _station(chain, _camera((0.0, 0.0, 0.0)), 0, np.r_[0.0, 0.0, 0.05, 0.1, 0.0, 0.0])
    again = StationChain()
    again.restore(chain.state())
    assert again.fixes == 1 and again.fix is not None and again.fix.fix_id == 1
    np.testing.assert_allclose(again.fix.correction, chain.fix.correction)  # type: ignore[union-attr]
    np.testing.assert_allclose(again.anchor_cov, chain.anchor_cov)  # type: ignore[arg-type]


def test_bad_fix_is_invalid() -> None:
    fix = NavFix.from_correction(1, 0.0, np.zeros(3), np.r_[0.0, 0.0, math.nan, 0, 0, 0], np.eye(6))
    assert not fix.valid()
    assert NavFix.from_correction(2, 0.0, np.zeros(3), np.zeros(6), np.eye(6)).valid()
