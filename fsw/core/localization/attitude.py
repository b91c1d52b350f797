"""The rover body's attitude and height for the camera pose chain (docs/algorithm.md §5.1, §1.2).

Roll and pitch come from the attitude sensor (``fsw.drivers.imu_can``: the accelerometer's
gravity direction at rest, averaged); the height of the body over the start is dead-reckoned
from the odometry's body-frame motion rotated by that attitude (on a slope the rover climbs
or descends as it drives), and the map registration (``fsw.core.registration.registration``) corrects
what remains. The uncertainty of all three joins the camera pose covariance
(``fsw.tasks.camera.camera_pose_covariance``) and through it every point of a view (§1.2).

When the sensor is faulted or silent the attitude is *unknown*, not level: the last good
roll and pitch are kept with the configured large sigma, so every view taken meanwhile
carries a pose covariance that says so.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from fsw.core.geometry import body_rotation

F64 = NDArray[np.float64]


class AttitudeSample(Protocol):
    @property
    def roll(self) -> float: ...

    @property
    def pitch(self) -> float: ...

    @property
    def cov(self) -> F64: ...


@dataclass(frozen=True)
class BodyAttitude:
    """Roll and pitch (rad), body height ``z_m`` over the start, their 3x3 covariance (roll,
    pitch, z) and whether the attitude came from a healthy sensor."""

    roll: float
    pitch: float
    z_m: float
    cov: F64
    valid: bool


class AttitudeTracker:
    """Holds the latest attitude and integrates the body height from the odometry."""

    def __init__(self, unknown_sigma_deg: float = 5.0, z_sigma_per_m: float = 0.02) -> None:
        self.unknown_var = math.radians(unknown_sigma_deg) ** 2
        self.z_sigma_per_m = z_sigma_per_m
        self.roll = self.pitch = self.z_m = 0.0
        self.att_cov = np.eye(2) * self.unknown_var
        self.z_sigma_m = 0.0
        self.valid = False

    def update(self, sample: AttitudeSample | None) -> None:
        """Take the sensor's estimate, or mark the attitude unknown (``None``)."""
        if sample is None or not (math.isfinite(sample.roll) and math.isfinite(sample.pitch)):
            self.valid = False
            self.att_cov = np.eye(2) * self.unknown_var
            return
        self.roll, self.pitch = float(sample.roll), float(sample.pitch)
        self.att_cov = np.asarray(sample.cov, dtype=np.float64).reshape(2, 2)
        self.valid = True

    def integrate(self, motion_body: F64, yaw: float) -> None:
        """Add the height change of a body-frame odometry step ``(dx, dy, dyaw)`` (m, m, rad).

        ``dz = e_z . R_body (dx, dy, 0)``; its sigma grows with the attitude sigma times the
        distance (a tilt error is a slope error) and with ``z_sigma_per_m`` times ``|dz|``
        (slip along the slope).
        """
        dx, dy = float(motion_body[0]), float(motion_body[1])
        if not (math.isfinite(dx) and math.isfinite(dy)):
            return
        R = body_rotation(yaw, self.pitch, self.roll)
        dz = float(R[2, 0] * dx + R[2, 1] * dy)
        s_att = math.sqrt(float(np.trace(self.att_cov)))
        self.z_m += dz
        self.z_sigma_m += math.hypot(dx, dy) * s_att + self.z_sigma_per_m * abs(dz)

    def reset(self, z_m: float = 0.0, z_sigma_m: float = 0.0) -> None:
        """Set the body height and its sigma (SET_ODOMETRY, or a registered view fed back)."""
        self.z_m, self.z_sigma_m = z_m, z_sigma_m

    def state(self) -> BodyAttitude:
        cov = np.zeros((3, 3))
        cov[:2, :2] = self.att_cov
        cov[2, 2] = self.z_sigma_m**2
        return BodyAttitude(self.roll, self.pitch, self.z_m, cov, self.valid)
