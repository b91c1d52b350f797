"""The Cliff-bot's camera head (fsw.core.team.cliffbot_head; docs/team.md, "Both agents sense")."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fsw.core.team.cliffbot_head import head_camera_pose, head_end, head_pose_covariance, normal_from_attitude


@pytest.mark.parametrize(("yaw", "roll", "pitch"), [(0.0, 0.0, 0.0), (-1.2, 0.1, -0.6), (2.5, -0.3, 0.4)])
def test_the_normal_gives_back_the_attitude_sensors_roll_and_pitch(yaw: float, roll: float, pitch: float) -> None:
    """The bench's attitude sensor: sin pitch = -n . forward, sin roll = n . left."""
    n = normal_from_attitude(yaw, roll, pitch)
    fwd = np.array([math.cos(yaw), math.sin(yaw), 0.0])
    left = np.array([-math.sin(yaw), math.cos(yaw), 0.0])
    assert abs(float(np.linalg.norm(n)) - 1.0) < 1e-12 and n[2] > 0
    assert math.asin(-float(n @ fwd)) == pytest.approx(pitch, abs=1e-9)
    assert math.asin(float(n @ left)) == pytest.approx(roll, abs=1e-9)


def test_the_head_looks_ahead_from_the_front_and_back_or_sideways_from_the_rear() -> None:
    assert head_end(0.0, 0.4) == 0.4 and head_end(math.radians(45), 0.4) == 0.4
    assert head_end(math.radians(90), 0.4) == -0.4 and head_end(math.pi, 0.4) == -0.4
    n = normal_from_attitude(0.0, 0.0, math.radians(-30))  # nose down a 30 degree slope
    p = head_camera_pose(np.zeros(3), n, 0.0, 0.0, math.radians(-40), 0.45, 0.4)
    # 0.45 m along the normal, 0.4 m forward along the slope (down it), looking ahead and down
    expect = 0.45 * n + 0.4 * np.array([math.cos(math.radians(30)), 0.0, -math.sin(math.radians(30))])
    assert np.allclose(p.t, expect) and p.R[:, 2] @ np.array([1.0, 0.0, 0.0]) > 0.7 and p.R[2, 2] < -0.6


def test_the_pose_covariance_carries_the_estimates_error() -> None:
    xy, cov3 = np.array([1.0, 2.0]), np.diag([0.02 ** 2, 0.03 ** 2, math.radians(2.0) ** 2])
    pose, cov = head_pose_covariance(xy, 0.5, 0.3, 0.0, 0.0, 0.0, -0.7, 0.45, 0.4, cov3, 0.0, 0.0)
    assert cov.shape == (6, 6) and np.allclose(cov, cov.T)
    assert cov[5, 5] == pytest.approx(0.0, abs=1e-12)  # no height or tilt error: the head's height is exact
    assert cov[2, 2] == pytest.approx(math.radians(2.0) ** 2, rel=1e-3)  # heading: about the vertical
    # the head is 0.4 m ahead: a heading error moves it sideways, on top of the estimate's xy error
    assert cov[3, 3] + cov[4, 4] > 0.02 ** 2 + 0.03 ** 2
    zero = head_pose_covariance(xy, 0.5, 0.3, 0.0, 0.0, 0.0, -0.7, 0.45, 0.4, np.zeros((3, 3)), 0.0, 0.0)[1]
    assert np.allclose(zero, 0.0) and np.allclose(pose.t[2], 0.95)
    tilted = head_pose_covariance(xy, 0.5, 0.3, 0.0, 0.0, 0.0, -0.7, 0.45, 0.4, cov3, 0.05, 0.0)[1]
    assert tilted[5, 5] == pytest.approx(0.05 ** 2, rel=1e-3)


def _hidden_by_the_body(eye: np.ndarray, p: np.ndarray, half: np.ndarray) -> bool:
    """Whether the sight line from ``eye`` to ``p`` passes through the body's box (body frame:
    x along the heading, z up from its ground, the box from 5 cm up as the mask takes it)."""
    for t in np.linspace(0.02, 0.98, 80):
        q = eye + t * (p - eye)
        if abs(q[0]) < half[0] and abs(q[1]) < half[1] and 0.05 < q[2] < 2.0 * half[2]:
            return True
    return False


def _unseen(sc: object, points: list[np.ndarray]) -> list[tuple[float, float]]:
    """The ground points (flat ground, heading +x) that no pointing of the scan ``sc`` sees: in its
    camera's field of view and usable depth, the sight line clear of the body's box."""
    from fsw.core.geometry import CameraConfig
    from fsw.sections import CliffbotSensingConfig

    assert isinstance(sc, CliffbotSensingConfig)
    cam = CameraConfig(width_px=sc.width_px, height_px=sc.height_px, hfov_deg=sc.hfov_deg,
                       baseline_m=sc.baseline_m, min_range_m=sc.min_range_m, max_range_m=sc.max_range_m)
    half_w, half_h = math.tan(math.radians(sc.hfov_deg) / 2), math.tan(cam.vfov_rad / 2)
    half = np.asarray(sc.body_half_m, float)
    out = []
    for p in points:
        seen = False
        for k, pan_deg in enumerate(sc.pan_deg):
            pose = head_camera_pose(np.zeros(3), np.array([0.0, 0.0, 1.0]), 0.0, math.radians(pan_deg),
                                    math.radians(sc.tilt_of(k)), sc.head_m, sc.end_of(k))
            x, y, z = pose.R.T @ (p - pose.t)  # camera frame: right, down, forward
            rng = float(np.linalg.norm(p - pose.t))
            if (z > 0 and abs(x / z) <= half_w and abs(y / z) <= half_h and sc.min_range_m <= rng <= sc.max_range_m
                    and not _hidden_by_the_body(pose.t, p, half)):
                seen = True
                break
        if not seen:
            out.append((round(float(p[0]), 2), round(float(p[1]), 2)))
    return out


def test_the_default_scan_sees_the_ground_beside_both_ends() -> None:
    """The ground beside the body's ends (the corners, up to 0.24 m past each end and 0.45 m to
    either side) is where the plane under the body is carried on and where its next step's
    footprint lies; the head, 0.45 m up at an end and lower than the body's top, sees it only from
    that end, looking steeply down and back along the body (a pan past 90 deg from the front end,
    under 90 deg from the rear end): the scan's head_ends put those pointings there. (Beside the
    body's middle no head at either end sees past the box: a limit, docs/team.md.)"""
    from fsw.sections import CliffbotSensingConfig

    sc = CliffbotSensingConfig()
    ends = [np.array([s * a, c * side, 0.0]) for s in (1.0, -1.0) for a in np.arange(0.32, 0.56, 0.04)
            for c in np.arange(0.05, 0.46, 0.05) for side in (1.0, -1.0)]
    assert _unseen(sc, ends) == []
    # the scan of ten pointings, each from the end its pan gives, left them unseen
    ten = CliffbotSensingConfig(pan_deg=sc.pan_deg[:10], tilts_deg=sc.tilts_deg[:10], head_ends=())
    assert len(_unseen(ten, ends)) > 40


def test_a_scan_whose_head_ends_do_not_fit_is_refused() -> None:
    from fsw.sections import CliffbotSensingConfig

    with pytest.raises(ValueError, match="head_ends"):
        CliffbotSensingConfig(head_ends=(1.0,))
    with pytest.raises(ValueError, match="head_ends"):
        CliffbotSensingConfig(head_ends=(0.5,) * 16)
    sc = CliffbotSensingConfig()
    assert sc.end_of(0) == sc.head_end_m and sc.end_of(4) == -sc.head_end_m  # ahead, behind: by the pan
    assert sc.end_of(12) == sc.head_end_m and sc.end_of(14) == -sc.head_end_m  # named
