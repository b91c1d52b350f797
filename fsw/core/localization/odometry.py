"""Dead reckoning from the wheel encoders, with a covariance that grows with the path
(docs/algorithm.md §5: the pose prior that localization refines).

Each update takes the drive wheels' positions (rad) and the steering angles; the body motion
is the least-squares rigid motion of the four wheel displacements
(``wheel_kinematics.body_motion``). The 1-sigma position error grows by ``odo_sigma_per_m``
per metre driven, the yaw error by ``odo_yaw_sigma_per_rad`` per radian turned plus the same
per-metre term, from the last correction (``correct``: a registered view fed back,
``fsw.core.localization.nav_fix``), whose covariance is the base it grows from. A heading error carries
on into position as the rover drives (a wheel that slips more on one side bends the path):
the position sigma also grows by the heading sigma integrated over the distance driven,
``integral sigma_yaw(s) ds`` (:func:`drift_sigma`; the errors are systematic, so sigmas add).

A correction's covariance is relative to the map the view registered on, not to the rover's
start (the team's frame): the map there holds the pose error of the views that built it, which
were registered in turn on the map before them. :meth:`Odometry.frame_covariance` is the
covariance against the start: the corrections' covariances summed along that chain (each
registration's error is independent of the one before, so variances add; taking every
correction as a link is the upper end) plus the growth since the last one
(docs/algorithm.md §5.2, "A fix without a plate").
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from fsw.core.motion import wheel_kinematics as wk
from fsw.core.motion.motion_profile import MotionConfig, Pose3

F64 = NDArray[np.float64]
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
        self._last_seen: list[float] | None = None  # the drive positions of the last update
        # covariance()'s last inputs (the arrays held, so identity is safe) and result
        self._cov: tuple[tuple[float, ...], NDArray[np.float64], MotionConfig, NDArray[np.float64]] | None = None
        self.base_cov = np.zeros((3, 3))  # (x, y, yaw) covariance at the last correction
        self.frame_cov = np.zeros((3, 3))  # the corrections' covariances summed (frame_covariance)
        self.path0 = self.turned0 = 0.0  # path and turn at the last correction (growth since)
        self.lever_path = self.lever_turn = 0.0  # integrals of (path, turn) since it over distance

    def update(self, drive_rad: Sequence[float], steer_rad: Sequence[float]) -> NDArray[np.float64] | None:
        """Integrate the motion since the previous wheel positions (the first call only records);
        returns the body motion ``(dx, dy, dyaw)`` in the body frame, or None on the first call
        and when no drive wheel turned (a rover standing still: nothing to integrate, and no
        arithmetic spent on it: 10 Hz, most of a mission)."""
        if self._resume_drive is None and self._last_seen is not None and list(drive_rad) == self._last_seen:
            return None
        self._last_seen = list(drive_rad)
        drive, steer = np.asarray(drive_rad, np.float64), np.asarray(steer_rad, np.float64)
        motion: NDArray[np.float64] | None = None
        if self._resume_drive is not None:  # resumed: keep the baseline if the counts survived
            saved, self._resume_drive = self._resume_drive, None
            agree = bool(np.all(np.abs(drive - saved) < RESUME_ENCODER_TOL_RAD))
            self._last_drive = saved if agree else drive
        if self._last_drive is not None:
            motion = wk.body_motion((drive - self._last_drive) * self.r, steer, self.pinv)
            self.pose = wk.integrate_pose(self.pose, motion)
            ds = math.hypot(motion[0], motion[1])
            self.lever_path += (self.path_m - self.path0) * ds
            self.lever_turn += (self.turned_rad - self.turned0) * ds
            self.path_m += ds
            self.turned_rad += abs(motion[2])
            self.yaw_acc += float(motion[2])
        self._last_drive = drive
        return motion

    def reset(self, pose: Pose3) -> None:
        """Set the pose (SET_ODOMETRY); the accumulated error starts again from zero."""
        self.pose = pose
        self.path_m = self.turned_rad = self.path0 = self.turned0 = 0.0
        self.lever_path = self.lever_turn = 0.0
        self.base_cov = np.zeros((3, 3))
        self.frame_cov = np.zeros((3, 3))

    def correct(self, pose: Pose3, cov: NDArray[np.float64]) -> None:
        """Take a corrected pose and its (x, y, yaw) covariance; the error grows from there.
        ``yaw_acc`` moves with the yaw (a turn segment closes on it; corrections are applied
        between moves only)."""
        self.yaw_acc += math.remainder(pose[2] - self.pose[2], math.tau)
        self.pose = pose
        self.base_cov = 0.5 * (np.asarray(cov, np.float64) + np.asarray(cov, np.float64).T)
        self.frame_cov = self.frame_cov + self.base_cov
        self.path0, self.turned0 = self.path_m, self.turned_rad
        self.lever_path = self.lever_turn = 0.0

    def state(self) -> dict[str, object]:
        """The dead-reckoned pose, its growth terms and the drive encoder baseline (JSON)."""
        last = None if self._last_drive is None else self._last_drive.tolist()
        return {"pose": list(self.pose), "path_m": self.path_m, "turned_rad": self.turned_rad,
                "yaw_acc": self.yaw_acc, "last_drive": last, "base_cov": self.base_cov.tolist(),
                "path0": self.path0, "turned0": self.turned0, "lever": [self.lever_path, self.lever_turn],
                "frame_cov": self.frame_cov.tolist()}

    def restore(self, pose: Pose3, path_m: float, turned_rad: float, yaw_acc: float,
                last_drive: NDArray[np.float64] | None) -> None:
        """Continue a checkpointed dead reckoning (a resumed mission). The encoder baseline is
        kept only if the first reading after the restart agrees with it within
        ``RESUME_ENCODER_TOL_RAD`` (the controllers kept their counts); otherwise integration
        starts again from that reading."""
        self.pose, self.path_m, self.turned_rad, self.yaw_acc = pose, path_m, turned_rad, yaw_acc
        self._resume_drive = last_drive

    def restore_correction(self, base_cov: NDArray[np.float64], path0: float, turned0: float,
                           lever: tuple[float, float] = (0.0, 0.0), frame_cov: NDArray[np.float64] | None = None
                           ) -> None:
        """The last correction of a checkpointed dead reckoning (see ``correct``); ``frame_cov``
        the corrections' sum (None: a checkpoint without it, the last correction's alone)."""
        self.base_cov = np.asarray(base_cov, np.float64).reshape(3, 3)
        self.frame_cov = self.base_cov.copy() if frame_cov is None else np.asarray(frame_cov, np.float64).reshape(3, 3)
        self.path0, self.turned0 = path0, turned0
        self.lever_path, self.lever_turn = lever

    def covariance(self, cfg: MotionConfig) -> NDArray[np.float64]:
        """3x3 covariance of (x, y, yaw): the last correction's and the growth since (with the
        heading error carried into position over the distance driven)."""
        key = (self.path_m, self.path0, self.turned_rad, self.turned0, self.lever_path, self.lever_turn)
        memo = self._cov
        if memo is not None and memo[0] == key and memo[1] is self.base_cov and memo[2] is cfg:
            return memo[3]  # unchanged (standing still): the same read-only array (10 Hz)
        path, turned = self.path_m - self.path0, self.turned_rad - self.turned0
        s_yaw = cfg.odo_yaw_sigma_per_rad * turned + cfg.odo_sigma_per_m * path
        s_xy = float(position_sigma(path, math.sqrt(max(float(self.base_cov[2, 2]), 0.0)),
                                    self.lever_path, self.lever_turn, cfg))
        cov = self.base_cov + np.diag([s_xy**2, s_xy**2, s_yaw**2])
        cov.setflags(write=False)
        self._cov = (key, self.base_cov, cfg, cov)
        return cov

    def frame_covariance(self, cfg: MotionConfig) -> NDArray[np.float64]:
        """3x3 covariance of (x, y, yaw) against the rover's start, not its map (module
        docstring): :meth:`covariance` plus the earlier corrections' covariances."""
        return self.covariance(cfg) + (self.frame_cov - self.base_cov)


def position_sigma(path_m: F64 | float, sigma_yaw0: float, lever_path: F64 | float, lever_turn: F64 | float,
                   cfg: MotionConfig) -> F64 | float:
    """The odometry's position sigma grown over ``path_m`` driven (the one model of the drift):
    ``k s + sigma_yaw0 s + k_turn integral(turned ds) + k integral(s ds)``, the last three the
    heading sigma integrated over the distance; ``lever_path`` and ``lever_turn`` are those two
    integrals."""
    return (cfg.odo_sigma_per_m * path_m + sigma_yaw0 * path_m
            + cfg.odo_yaw_sigma_per_rad * lever_turn + cfg.odo_sigma_per_m * lever_path)


def drift_sigma(sigma_xy0: float, sigma_yaw0: float, path_m: NDArray[np.float64], turned_rad: NDArray[np.float64],
                cfg: MotionConfig) -> NDArray[np.float64]:
    """Position sigma along a planned move (``Odometry.covariance``'s growth): ``path_m`` and
    ``turned_rad`` are the distance and the turn accumulated at each sample from its start,
    where the pose has sigmas ``sigma_xy0`` and ``sigma_yaw0``."""
    s = np.asarray(path_m, np.float64)
    t = np.asarray(turned_rad, np.float64)
    ds = np.diff(s, prepend=s[:1] if s.size else s)
    grown = position_sigma(np.cumsum(ds), sigma_yaw0, np.cumsum(s * ds), np.cumsum(t * ds), cfg)
    return np.asarray(sigma_xy0 + grown, np.float64)
