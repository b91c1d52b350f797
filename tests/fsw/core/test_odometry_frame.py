"""The rover's covariance against its start (fsw/core/localization/odometry.py): a correction's
covariance is relative to the map it registered on; ``frame_covariance`` adds the corrections
before it (the map's own errors), survives a checkpoint, and the fixer carries it into the
camera pose of a fix that rests on the rover's estimate (fsw/tasks/fixer/fix_pose.py)."""

from __future__ import annotations

import math

import numpy as np

from fsw.core.geometry import MastConfig
from fsw.core.localization.odometry import Odometry
from fsw.core.motion import wheel_kinematics as wk
from fsw.core.motion.motion_profile import MotionConfig
from fsw.tasks.fixer.fix_pose import fix_camera, frame_extra
from fsw.tasks.messages import NavPose
from fsw.tasks.motion_state import MotionSection

WHEEL_XY = np.array([[0.3, 0.25], [0.3, -0.25], [-0.3, 0.25], [-0.3, -0.25]])


def _odo() -> Odometry:
    return Odometry(0.1, wk.body_motion_matrix(WHEEL_XY))


def test_the_frame_covariance_sums_the_corrections_and_survives_a_checkpoint() -> None:
    cfg = MotionConfig()
    odo = _odo()
    odo.update([0.0] * 4, [0.0] * 4)
    assert np.allclose(odo.frame_covariance(cfg), odo.covariance(cfg))  # no correction: the same
    a, b = np.diag([4e-4, 1e-4, 3e-4]), np.diag([1e-4, 2e-4, 1e-4])
    odo.correct((0.0, 0.0, 0.0), a)
    odo.update([2.0] * 4, [0.0] * 4)  # 0.2 m: the growth since the correction
    odo.correct(odo.pose, b)
    odo.update([5.0] * 4, [0.0] * 4)
    grown = odo.covariance(cfg)
    assert np.allclose(grown[2, 2], b[2, 2] + (cfg.odo_sigma_per_m * 0.3) ** 2)  # relative to the map: b only
    assert np.allclose(odo.frame_covariance(cfg), grown + a)  # against the start: a as well
    section = MotionSection.from_json({**odo.state(), "done": 0, "aborted": 0, "steer_hold": [0.0] * 4})
    back = _odo()
    section.apply_odometry(back)
    assert np.allclose(back.frame_covariance(cfg), odo.frame_covariance(cfg))
    old = {k: v for k, v in odo.state().items() if k != "frame_cov"}  # a checkpoint from before it
    older = _odo()
    MotionSection.from_json({**old, "done": 0, "aborted": 0, "steer_hold": [0.0] * 4}).apply_odometry(older)
    assert np.allclose(older.frame_covariance(cfg), older.covariance(cfg))


def test_a_fix_without_plates_carries_the_maps_heading_error_over_its_lever() -> None:
    from fsw.settings import load_settings

    cfg = load_settings()
    s_yaw = math.radians(2.0)
    nav = NavPose(0.0, 1.0, 2.0, 0.3, np.diag([1e-4, 1e-4, 1e-6]), (0.4, -0.5, 0.3),
                  frame_cov=np.diag([1e-4, 1e-4, 1e-6 + s_yaw**2]))
    extra = frame_extra(nav, cfg)
    assert math.isclose(extra[2, 2], s_yaw**2, rel_tol=1e-3)  # the heading about the vertical
    mast: MastConfig = cfg.mast
    lever = math.hypot(mast.base_x_m, mast.base_y_m)  # the camera turns about the body's origin
    assert math.isclose(extra[3, 3] + extra[4, 4], (lever * s_yaw) ** 2, rel_tol=1e-2)
    from fsw.core.geometry import CameraPose

    pose, cov = CameraPose(np.eye(3), np.zeros(3)), np.eye(6) * 1e-6
    assert np.allclose(fix_camera([], pose, cov, np.zeros((6, 6)), extra).cov, cov + extra)
    assert np.allclose(frame_extra(NavPose(0.0, 1.0, 2.0, 0.3, np.eye(3), (0.0, 0.0, 0.3)), cfg), 0.0)
