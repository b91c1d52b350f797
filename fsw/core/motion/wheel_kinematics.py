"""Kinematics of the SRR-like rover: four independently steered and driven wheels.

Pure functions on arrays (no I/O). They carry out the motions that docs/algorithm.md §3.3 costs
(drive along the edge path, turn in place) and give the dead-reckoning pose prior that §5
localization refines.

* Body frame: x forward, y left, origin at the body centre; wheels in the order
  FL, FR, RL, RR at ``(+-wheelbase/2, +-track/2)``.
* A wheel's steer angle is the direction of its rolling velocity in the body frame, folded
  into [-pi/2, pi/2] by reversing the drive (a steering joint never needs more).
* Odometry: each wheel reports the distance it rolled along its steer direction; the body
  motion is the least-squares rigid motion that explains all four (8 equations, 3
  unknowns), so wheel slip shows up as drift, not as a contradiction.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from fsw.core.geometry import RoverConfig, wrap_angle

F64 = NDArray[np.float64]
WHEEL_ORDER = ("FL", "FR", "RL", "RR")


def wheel_positions(rover: RoverConfig) -> F64:
    """(4, 2) wheel contact points in the body frame, FL, FR, RL, RR."""
    a, b = rover.wheelbase_m / 2.0, rover.track_m / 2.0
    return np.array([[a, b], [a, -b], [-a, b], [-a, -b]], dtype=float)


def wheel_velocities(vx: float, vy: float, wz: float, wheel_xy: F64) -> F64:
    """(4, 2) velocity of each wheel contact for the body twist ``(vx, vy, wz)``."""
    return np.column_stack([vx - wz * wheel_xy[:, 1], vy + wz * wheel_xy[:, 0]])


def wheel_commands(
    vx: float, vy: float, wz: float, wheel_xy: F64, wheel_radius_m: float, steer_hold: F64 | None = None
) -> tuple[F64, F64]:
    """Steer angles (rad) and wheel rates (rad/s) that realise the body twist.

    A wheel that need not move keeps ``steer_hold`` (default 0).
    """
    v = wheel_velocities(vx, vy, wz, wheel_xy)
    speed = np.hypot(v[:, 0], v[:, 1])
    steer = np.arctan2(v[:, 1], v[:, 0])
    rate = speed / wheel_radius_m
    flip = np.abs(steer) > math.pi / 2 + 1e-12
    steer = np.where(flip, steer - np.sign(steer) * math.pi, steer)
    rate = np.where(flip, -rate, rate)
    still = speed < 1e-9
    hold = np.zeros(4) if steer_hold is None else np.asarray(steer_hold, float)
    return np.where(still, hold, steer), np.where(still, 0.0, rate)


def body_motion_matrix(wheel_xy: F64) -> F64:
    """Pseudo-inverse mapping stacked wheel displacements (8,) to body motion (dx, dy, dpsi)."""
    rows = []
    for x, y in wheel_xy:
        rows += [[1.0, 0.0, -y], [0.0, 1.0, x]]
    return np.linalg.pinv(np.array(rows))


def body_motion(roll_m: F64, steer_rad: F64, pinv: F64) -> F64:
    """Least-squares body motion ``(dx, dy, dpsi)`` (body frame) from wheel roll distances."""
    d = np.asarray(roll_m, float)
    s = np.asarray(steer_rad, float)
    disp = np.column_stack([d * np.cos(s), d * np.sin(s)]).ravel()
    return np.asarray(pinv @ disp, dtype=float)


def integrate_pose(pose: tuple[float, float, float], motion: F64) -> tuple[float, float, float]:
    """Compose a world pose ``(x, y, yaw)`` with a body-frame motion (midpoint heading)."""
    x, y, yaw = pose
    dx, dy, dpsi = (float(v) for v in motion)
    mid = yaw + dpsi / 2.0
    c, s = math.cos(mid), math.sin(mid)
    yaw2 = wrap_angle(yaw + dpsi)
    return (x + c * dx - s * dy, y + s * dx + c * dy, yaw2)

