"""The Cliff-bot's camera head (fsw.core.team.cliffbot_head; docs/team.md, "Both agents sense")."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fsw.core.geometry import normal_from_attitude
from fsw.core.team.cliffbot_head import head_camera_pose, head_end, head_pose_covariance


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


def test_a_pointing_of_the_scan_may_name_the_end_it_is_taken_from() -> None:
    """Looking ahead and sideways from the rear end (the ground beside the body's rear half), and
    back and sideways from the front end (beside its front corners): the pan alone does not say."""
    assert head_end(math.radians(60), 0.4, "rear") == -0.4 and head_end(math.radians(-120), 0.4, "front") == 0.4
    assert head_end(math.radians(60), 0.4, "") == 0.4 and head_end(math.radians(-120), 0.4, "") == -0.4


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
