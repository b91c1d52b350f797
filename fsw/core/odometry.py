"""Dead reckoning from the wheel encoders, with a covariance that grows with the path
(ALGORITHM.md §5: the pose prior that localization refines).

Each update takes the drive wheels' positions (rad) and the steering angles; the body motion
is the least-squares rigid motion of the four wheel displacements
(``wheel_kinematics.body_motion``). The 1-sigma position error grows by ``odo_sigma_per_m``
per metre driven, the yaw error by ``odo_yaw_sigma_per_rad`` per radian turned plus the same
per-metre term.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from fsw.core import wheel_kinematics as wk
from fsw.core.motion_profile import MotionConfig, Pose3

RESUME_ENCODER_TOL_RAD = 0.05


class Odometry:
    """The dead-reckoned pose of the rover body and the distance and angle it accumulated."""

    def __init__(self, wheel_radius_m: float, pinv: NDArray[np.float64]) -> None:
        self.r, self.pinv = wheel_radius_m, pinv
        self.pose: Pose3 = (0.0, 0.0, 0.0)
        self.path_m = self.turned_rad = 0.0
        self.yaw_acc = 0.0  # signed yaw turned since start (turn segments close on it)
        self._last_drive: NDArray[np.float64] | None = None
        self._resume_drive: NDArray[np.float64] | None = None  # a restored encoder baseline

    def update(self, drive_rad: NDArray[np.float64], steer_rad: NDArray[np.float64]) -> NDArray[np.float64] | None:
        """Integrate the motion since the previous wheel positions (the first call only records);
        returns the body motion ``(dx, dy, dyaw)`` in the body frame, or None on the first call."""
        motion: NDArray[np.float64] | None = None
        if self._resume_drive is not None:  # resumed: keep the baseline if the counts survived
            saved, self._resume_drive = self._resume_drive, None
            agree = bool(np.all(np.abs(drive_rad - saved) < RESUME_ENCODER_TOL_RAD))
            self._last_drive = saved if agree else drive_rad
        if self._last_drive is not None:
            motion = wk.body_motion((drive_rad - self._last_drive) * self.r, steer_rad, self.pinv)
            self.pose = wk.integrate_pose(self.pose, motion)
            self.path_m += math.hypot(motion[0], motion[1])
            self.turned_rad += abs(motion[2])
            self.yaw_acc += float(motion[2])
        self._last_drive = drive_rad
        return motion

    def reset(self, pose: Pose3) -> None:
        """Set the pose (SET_ODOMETRY); the accumulated error starts again from zero."""
        self.pose = pose
        self.path_m = self.turned_rad = 0.0

    def state(self) -> dict[str, object]:
        """The dead-reckoned pose, its growth terms and the drive encoder baseline (JSON)."""
        last = None if self._last_drive is None else self._last_drive.tolist()
        return {"pose": list(self.pose), "path_m": self.path_m, "turned_rad": self.turned_rad,
                "yaw_acc": self.yaw_acc, "last_drive": last}

    def restore(self, pose: Pose3, path_m: float, turned_rad: float, yaw_acc: float,
                last_drive: NDArray[np.float64] | None) -> None:
        """Continue a checkpointed dead reckoning (a resumed mission). The encoder baseline is
        kept only if the first reading after the restart agrees with it within
        ``RESUME_ENCODER_TOL_RAD`` (the controllers kept their counts); otherwise integration
        starts again from that reading."""
        self.pose, self.path_m, self.turned_rad, self.yaw_acc = pose, path_m, turned_rad, yaw_acc
        self._resume_drive = last_drive

    def covariance(self, cfg: MotionConfig) -> NDArray[np.float64]:
        """3x3 covariance of (x, y, yaw)."""
        s_xy = cfg.odo_sigma_per_m * self.path_m
        s_yaw = cfg.odo_yaw_sigma_per_rad * self.turned_rad + cfg.odo_sigma_per_m * self.path_m
        return np.diag([s_xy**2, s_xy**2, s_yaw**2])
