"""Odometry on a rover standing still (issue 15): no drive wheel turned, nothing integrated,
the same state as integrating the zero motion; the next real motion integrates from there."""

from __future__ import annotations

import math

import numpy as np

from fsw.core.localization.odometry import Odometry
from fsw.core.motion import wheel_kinematics as wk

WHEEL_XY = np.array([[0.3, 0.25], [0.3, -0.25], [-0.3, 0.25], [-0.3, -0.25]])


def _odo() -> Odometry:
    return Odometry(0.1, wk.body_motion_matrix(WHEEL_XY))


def test_standing_still_integrates_nothing_and_moving_again_integrates() -> None:
    odo = _odo()
    assert odo.update([0.0] * 4, [0.0] * 4) is None  # the first reading only records
    for k in range(1, 6):
        odo.update([0.5 * k] * 4, [0.1] * 4)
    pose, path = odo.pose, odo.path_m
    for _ in range(20):  # standing, steering in place
        assert odo.update([2.5] * 4, [0.3] * 4) is None
    assert odo.pose == pose and odo.path_m == path
    motion = odo.update([3.0] * 4, [0.0] * 4)  # drives 0.05 m straight ahead (body frame)
    assert motion is not None and math.isclose(float(motion[0]), 0.05, rel_tol=1e-9)
    assert math.isclose(odo.path_m, path + 0.05, rel_tol=1e-9)


def test_a_resumed_baseline_is_still_checked_on_the_first_reading() -> None:
    odo = _odo()
    odo.update([1.0] * 4, [0.0] * 4)
    odo.restore((1.0, 2.0, 0.0), 3.0, 0.0, 0.0, np.array([0.98] * 4))  # the checkpoint's baseline
    motion = odo.update([1.0] * 4, [0.0] * 4)  # the reading seen before the restart: not "still"
    assert motion is not None and math.isclose(float(motion[0]), 0.002, rel_tol=1e-6)


def test_the_covariance_is_recomputed_only_when_its_inputs_change() -> None:
    from fsw.core.motion.motion_profile import MotionConfig

    cfg, odo = MotionConfig(), _odo()
    odo.update([0.0] * 4, [0.0] * 4)
    odo.update([1.0] * 4, [0.0] * 4)
    a = odo.covariance(cfg)
    assert odo.covariance(cfg) is a and not a.flags.writeable  # shared at 10 Hz: read-only
    odo.update([1.0] * 4, [0.0] * 4)  # standing
    assert odo.covariance(cfg) is a
    odo.update([2.0] * 4, [0.0] * 4)  # driven on
    b = odo.covariance(cfg)
    assert b is not a and b[0, 0] > a[0, 0]
    for k in range(2):  # two corrections with the same path: each one's own base covariance
        odo.correct(odo.pose, np.eye(3) * (k + 1) * 1e-4)
        assert odo.covariance(cfg)[0, 0] == (k + 1) * 1e-4
