"""True motion of the 3-DOF camera mast: pan, tilt and lift with limits and rates.

Joints slew toward their targets at the rates of ``MastConfig`` and stop at its limits. The
encoders read the joint positions; the optical axis actually points at ``encoder + offset``,
a seeded calibration error per joint, so the flight software's camera pose is close to, not
equal to, the truth. A stalled mast (fault injection) does not move. The camera pose follows
``fsw.core.geometry``'s conventions and includes the body's pitch and roll from the rover.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fsw.core.geometry import CameraPose, MastConfig, rotation_from_yaw_tilt
from fsw.framework.params import param

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class MastTruthConfig:
    pan_offset_sigma_deg: float = param(0.1, lo=0.0, hi=5.0, units="deg", doc="pan calibration error")
    tilt_offset_sigma_deg: float = param(0.1, lo=0.0, hi=5.0, units="deg", doc="tilt calibration error")
    lift_offset_sigma_m: float = param(0.001, lo=0.0, hi=0.1, units="m", doc="lift calibration error")
    park_pan_deg: float = param(0.0, lo=-180.0, hi=180.0, units="deg", doc="joints at power-on")
    park_tilt_deg: float = param(0.0, lo=-90.0, hi=90.0, units="deg")
    park_lift_m: float = param(0.0, lo=0.0, hi=2.0, units="m")


class MastTruth:
    """Joint state ``q = (pan, tilt, lift)`` (rad, rad, m) with slewing toward ``target``."""

    def __init__(self, mast: MastConfig, cfg: MastTruthConfig, seed: int) -> None:
        self.mast, self.cfg = mast, cfg
        rng = np.random.default_rng(seed)
        self.q = np.array(mast.clamp(math.radians(cfg.park_pan_deg), math.radians(cfg.park_tilt_deg), cfg.park_lift_m))
        self.target = self.q.copy()
        self.offset = np.array(
            [math.radians(cfg.pan_offset_sigma_deg), math.radians(cfg.tilt_offset_sigma_deg), cfg.lift_offset_sigma_m]
        ) * rng.standard_normal(3)
        self.rates = np.array([math.radians(mast.pan_rate_dps), math.radians(mast.tilt_rate_dps), mast.lift_rate_mps])
        self.stalled = False
        self.travel = np.zeros(3)  # accumulated |motion| per joint

    def set_target(self, pan: float, tilt: float, lift: float) -> None:
        self.target = np.array(self.mast.clamp(pan, tilt, lift))

    def hold(self) -> None:
        self.target = self.q.copy()

    def step(self, dt_s: float) -> None:
        if self.stalled:
            return
        step = np.clip(self.target - self.q, -self.rates * dt_s, self.rates * dt_s)
        self.q = np.array(self.mast.clamp(*(self.q + step)))
        self.travel += np.abs(step)

    @property
    def moving(self) -> bool:
        return bool(np.any(np.abs(self.target - self.q) > np.array([1e-6, 1e-6, 1e-7])))

    @property
    def encoder(self) -> tuple[float, float, float]:
        return (float(self.q[0]), float(self.q[1]), float(self.q[2]))

    @property
    def true_joints(self) -> tuple[float, float, float]:
        t = self.q + self.offset
        return (float(t[0]), float(t[1]), float(t[2]))

    def camera_pose(self, body_origin: F64, body_R: F64) -> CameraPose:
        """Left-camera pose for a body at ``body_origin`` (ground under its centre) and attitude."""
        pan, tilt, lift = self.true_joints
        m = self.mast
        t = body_origin + body_R @ np.array([m.base_x_m, m.base_y_m, m.base_z_m + lift])
        R = body_R @ rotation_from_yaw_tilt(pan, tilt)
        return CameraPose(R, t)
