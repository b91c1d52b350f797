"""The camera pose chain with rover roll and pitch (issue 13, item 1; docs/algorithm.md §5.1) against
hand-computed cases, the attitude uncertainty in the pose covariance (§1.2), and the body
height dead-reckoned on a slope."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fsw.core.geometry import MastConfig, body_rotation, camera_pose_from_rover
from fsw.core.localization.attitude import AttitudeTracker
from fsw.core.localization.localization import so3_exp, so3_log
from fsw.tasks.camera import camera_pose_covariance
from fsw.tasks.messages import NavPose

MAST = MastConfig(base_x_m=0.3, base_y_m=0.0, base_z_m=1.0)
D10 = math.radians(10.0)
C10, S10 = math.cos(D10), math.sin(D10)


def test_body_rotation_hand_computed_axes() -> None:
    """Pitch 10 deg nose up: the nose points (cos10, 0, sin10); roll 10 deg left side up: the
    left axis points (0, cos10, sin10); yaw 90 then pitch: the nose points (0, cos, sin)."""
    np.testing.assert_allclose(body_rotation(0.0, D10, 0.0)[:, 0], [C10, 0.0, S10], atol=1e-12)
    np.testing.assert_allclose(body_rotation(0.0, 0.0, D10)[:, 1], [0.0, C10, S10], atol=1e-12)
    np.testing.assert_allclose(body_rotation(math.pi / 2, D10, 0.0)[:, 0], [0.0, C10, S10], atol=1e-12)
    R = body_rotation(0.7, -0.3, 0.4)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)


def test_camera_pose_pitched_rover_hand_computed() -> None:
    """Rover at the origin pitched 10 deg nose up, mast base (0.3, 0, 1.0), lift 0.5, pan 0,
    tilt 0: centre = Ry(-10 deg) (0.3, 0, 1.5) = (0.3 cos10 - 1.5 sin10, 0, 0.3 sin10 + 1.5 cos10),
    optical axis (cos10, 0, sin10), right axis (0, -1, 0)."""
    p = camera_pose_from_rover((0.0, 0.0, 0.0), (0.0, 0.0, 0.5), MAST, 0.0, (0.0, D10))
    np.testing.assert_allclose(p.t, [0.3 * C10 - 1.5 * S10, 0.0, 0.3 * S10 + 1.5 * C10], atol=1e-12)
    np.testing.assert_allclose(p.t, [0.03497, 0.0, 1.52931], atol=1e-5)
    np.testing.assert_allclose(p.R[:, 2], [C10, 0.0, S10], atol=1e-12)
    np.testing.assert_allclose(p.R[:, 0], [0.0, -1.0, 0.0], atol=1e-12)


def test_camera_pose_rolled_rover_with_pan_and_tilt_hand_computed() -> None:
    """Rover at (1, 2, z=0.2), yaw 0, rolled 10 deg (left side up), mast pan 90 deg (looking
    left), tilt -30 deg: the head leans to the right, centre = (1.3, 2 - 1.5 sin10,
    0.2 + 1.5 cos10); the optical axis is the body's (0, cos30, -sin30) rolled:
    (0, cos30 cos10 + sin30 sin10, cos30 sin10 - sin30 cos10)."""
    c30, s30 = math.cos(math.radians(30)), math.sin(math.radians(30))
    p = camera_pose_from_rover((1.0, 2.0, 0.0), (math.pi / 2, -math.radians(30), 0.5), MAST, 0.2, (D10, 0.0))
    np.testing.assert_allclose(p.t, [1.3, 2.0 - 1.5 * S10, 0.2 + 1.5 * C10], atol=1e-12)
    np.testing.assert_allclose(p.R[:, 2], [0.0, c30 * C10 + s30 * S10, c30 * S10 - s30 * C10], atol=1e-12)
    # rolled 10 deg and looking left, down 30: the axis dips 20 deg, as a hand sketch says
    assert math.degrees(math.asin(p.R[2, 2])) == pytest.approx(-20.0, abs=1e-9)


def test_level_attitude_gives_the_previous_pose_exactly() -> None:
    for yaw, pan, tilt in ((0.3, -1.0, -0.5), (-2.0, 0.4, 0.2)):
        a = camera_pose_from_rover((0.4, -0.2, yaw), (pan, tilt, 0.3), MAST)
        b = camera_pose_from_rover((0.4, -0.2, yaw), (pan, tilt, 0.3), MAST, 0.0, (1e-12, 0.0))
        np.testing.assert_allclose(a.R, b.R, atol=1e-9)
        np.testing.assert_allclose(a.t, b.t, atol=1e-9)


def test_so3_log_is_exact_for_small_angles() -> None:
    """cv2.Rodrigues returned 0 below ~1e-5 rad, which zeroed the rotation Jacobian of the
    camera pose covariance; the log must invert exp at every scale."""
    for a in (1.0, 1e-3, 1e-5, 1e-7):
        w = np.array([a, -0.5 * a, 0.25 * a])
        np.testing.assert_allclose(so3_log(so3_exp(w)), w, rtol=1e-6, atol=1e-15)


def test_attitude_sigma_enters_the_camera_pose_covariance() -> None:
    """With only the attitude uncertain (roll sigma 0.2, pitch sigma 0.1 deg, rover at yaw 0),
    the camera rotation covariance is that of roll about world x and pitch about world y, and
    the centre moves by the lever arm (1.5 m head height) times the angle."""
    sr, sp = math.radians(0.2), math.radians(0.1)
    att = np.diag([sr**2, sp**2, 0.0])
    nav = NavPose(0.0, 0.0, 0.0, 0.0, np.zeros((3, 3)), (0.0, -0.5, 0.5), roll=0.02, pitch=0.01, att_cov=att)
    _, cov = camera_pose_covariance(nav, MAST, (0.0, 0.0, 0.0))
    sd = np.sqrt(np.diag(cov))
    assert sd[0] == pytest.approx(sr, rel=0.02) and sd[1] == pytest.approx(sp, rel=0.02)
    assert sd[2] == pytest.approx(math.sin(0.01) * sr, rel=0.02)  # the roll axis is pitched 0.01 rad
    assert sd[4] == pytest.approx(1.5 * sr, rel=0.03)  # roll swings the head sideways
    # and without the attitude term (as before the sensor) the rotation part is the joints'
    nav0 = NavPose(0.0, 0.0, 0.0, 0.0, np.zeros((3, 3)), (0.0, -0.5, 0.5))
    _, cov0 = camera_pose_covariance(nav0, MAST, (math.radians(0.2), math.radians(0.2), 0.0))
    assert math.sqrt(cov0[2, 2]) == pytest.approx(math.radians(0.2), rel=0.02)  # pan: about world z


def test_height_dead_reckoned_on_a_slope_and_unknown_attitude() -> None:
    class Att:
        roll, pitch, cov = 0.0, D10, np.diag([1e-6, 1e-6])

    tr = AttitudeTracker(unknown_sigma_deg=5.0, z_sigma_per_m=0.02)
    tr.update(Att())
    for _ in range(10):
        tr.integrate(np.array([0.1, 0.0, 0.0]), yaw=0.3)  # 1 m forward, nose up 10 deg
    st = tr.state()
    assert st.z_m == pytest.approx(S10, abs=1e-12) and st.valid
    assert math.sqrt(st.cov[2, 2]) == pytest.approx(1.0 * math.sqrt(2e-6) + 0.02 * S10, rel=1e-6)
    tr.update(None)  # sensor lost: attitude unknown, kept with a large sigma, never level
    st = tr.state()
    assert not st.valid and st.pitch == D10 and math.sqrt(st.cov[0, 0]) == pytest.approx(math.radians(5.0))


def test_so3_log_equals_scipy_at_every_angle() -> None:
    """so3_log no longer imports scipy.spatial (flight memory, issue 15): the same rotation
    vectors as scipy's Rotation, from tiny angles to just under pi and for each dominant axis."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(3)
    axes = rng.normal(size=(300, 3))
    axes /= np.linalg.norm(axes, axis=1)[:, None]
    angles = np.concatenate([10.0 ** rng.uniform(-9, 0, 100), rng.uniform(0, np.pi, 100),
                             np.pi - 10.0 ** rng.uniform(-9, -1, 100)])
    for w in axes * angles[:, None]:
        R = so3_exp(w)
        np.testing.assert_allclose(so3_log(R), Rotation.from_matrix(R).as_rotvec(), rtol=1e-9, atol=1e-12)
    chain = np.eye(3)  # a long product of rotations (rounding-level non-orthogonality), as in flight
    for w in axes[:50] * 0.7:
        chain = chain @ so3_exp(w)
    np.testing.assert_allclose(so3_log(chain), Rotation.from_matrix(chain).as_rotvec(), rtol=1e-9, atol=1e-12)
