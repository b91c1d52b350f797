"""Wheel moves as segments on a trapezoidal speed profile (docs/algorithm.md §3: "move (mast + wheels)").

A move is a list of segments, each *steer* (wheels to their angles, drive stopped) then *move*
(drive straight or turn in place), closed on odometry: the commanded speed ramps up at the
configured acceleration, is capped by the speed limit, and ramps down so that the remaining
distance ``r`` is covered at ``v <= sqrt(2 a r)``, never below the creep speed. Pure: the
motion task feeds it the pose estimate and sends the wheel rates it returns.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from fsw.core.geometry import wrap_angle
from fsw.framework.params import param

SegmentKind = Literal["drive", "turn"]
SegmentPlan = list[tuple[SegmentKind, float, float]]  # (kind, amount m|rad signed, speed m/s|rad/s)
Pose3 = tuple[float, float, float]


@dataclass(frozen=True)
class MotionConfig:
    drive_speed_mps: float = param(0.15, lo=0.005, hi=5.0, units="m/s", doc="default drive speed")
    turn_rate_dps: float = param(15.0, lo=0.5, hi=360.0, units="deg/s", doc="default turn rate")
    accel_mps2: float = param(0.2, lo=0.01, hi=10.0, units="m/s^2")
    yaw_accel_dps2: float = param(30.0, lo=1.0, hi=1000.0, units="deg/s^2")
    min_speed_mps: float = param(0.01, lo=0.0, hi=1.0, units="m/s", doc="creep speed near the goal")
    steer_tolerance_deg: float = param(2.0, lo=0.1, hi=20.0, units="deg", doc="steered before driving")
    steer_timeout_s: float = param(4.0, lo=0.1, hi=60.0, units="s")
    position_tolerance_m: float = param(0.005, lo=0.0005, hi=0.5, units="m")
    yaw_tolerance_deg: float = param(0.3, lo=0.01, hi=10.0, units="deg")
    mast_tolerance_deg: float = param(0.3, lo=0.01, hi=10.0, units="deg")
    mast_lift_tolerance_m: float = param(0.003, lo=0.0001, hi=0.1, units="m")
    mast_timeout_s: float = param(20.0, lo=0.5, hi=600.0, units="s")
    odo_sigma_per_m: float = param(0.02, lo=0.0, hi=1.0, units="m/m", doc="odometry sigma growth per metre")
    odo_yaw_sigma_per_rad: float = param(0.02, lo=0.0, hi=1.0, units="rad/rad")


@dataclass
class Segment:
    """One segment of a wheel move in progress."""

    kind: SegmentKind
    amount: float  # m or rad, signed
    speed: float  # m/s or rad/s
    steer: NDArray[np.float64]
    phase: Literal["steer", "move"] = "steer"
    t_phase: float = 0.0
    origin: Pose3 = (0.0, 0.0, 0.0)
    yaw_acc0: float = 0.0
    cmd: float = 0.0  # last commanded speed (ramp)


def drive_plan(distance_m: float, speed_mps: float, cfg: MotionConfig) -> SegmentPlan:
    """Drive straight ``distance_m`` (negative: backwards); speed 0 means the default."""
    return [("drive", distance_m, speed_mps or cfg.drive_speed_mps)]


def turn_plan(angle_rad: float, rate_rps: float, cfg: MotionConfig) -> SegmentPlan:
    """Turn in place by ``angle_rad`` (CCW +); rate 0 means the default."""
    return [("turn", angle_rad, rate_rps or math.radians(cfg.turn_rate_dps))]


def goto_plan(pose: Pose3, x: float, y: float, yaw: float | None, speed_mps: float, cfg: MotionConfig) -> SegmentPlan:
    """Turn, drive, turn from ``pose`` to ``(x, y[, yaw])``; backs up rather than turning around."""
    px, py, pyaw = pose
    dist, heading = math.hypot(x - px, y - py), math.atan2(y - py, x - px)
    turn1 = wrap_angle(heading - pyaw)
    if abs(turn1) > math.pi / 2:  # closer to back up than to turn around
        turn1, dist = wrap_angle(turn1 - math.pi), -dist
    segs: SegmentPlan = []
    if dist > cfg.position_tolerance_m or -dist > cfg.position_tolerance_m:
        if abs(turn1) > math.radians(cfg.yaw_tolerance_deg):
            segs += turn_plan(turn1, 0.0, cfg)
        segs += drive_plan(dist, speed_mps, cfg)
        pyaw += turn1
    if yaw is not None and abs(wrap_angle(yaw - pyaw)) > math.radians(cfg.yaw_tolerance_deg):
        segs += turn_plan(wrap_angle(yaw - pyaw), 0.0, cfg)
    return segs


def remaining(seg: Segment, pose: Pose3, yaw_acc: float, cfg: MotionConfig,
              wheel_xy: NDArray[np.float64]) -> tuple[float, float, float, float]:
    """``(remaining, tolerance, acceleration, creep speed)`` of a moving segment, in its units
    (m or rad): a drive's progress is along its start heading, a turn's is the accumulated yaw."""
    if seg.kind == "drive":
        x0, y0, h0 = seg.origin
        done = (pose[0] - x0) * math.cos(h0) + (pose[1] - y0) * math.sin(h0)
        return seg.amount - done, cfg.position_tolerance_m, cfg.accel_mps2, cfg.min_speed_mps
    rem = seg.amount - (yaw_acc - seg.yaw_acc0)
    vmin = cfg.min_speed_mps / float(np.hypot(*wheel_xy[0]))
    return rem, math.radians(cfg.yaw_tolerance_deg), math.radians(cfg.yaw_accel_dps2), vmin


def arrived(seg: Segment, rem: float, tol: float) -> bool:
    return rem * math.copysign(1.0, seg.amount) <= tol


def ramp_speed(seg: Segment, rem: float, acc: float, vmin: float, dt_s: float) -> float:
    """The trapezoid: the next commanded speed (magnitude), and it becomes the segment's last."""
    speed = max(vmin, min(seg.speed, math.sqrt(2.0 * acc * abs(rem)), seg.cmd + acc * dt_s))
    seg.cmd = speed
    return speed
