"""The wheel-move profile and dead reckoning (fsw/core/motion/motion_profile.py, fsw/core/localization/odometry.py),
pure: no drivers, no executive."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fsw.core.geometry import RoverConfig
from fsw.core.localization.odometry import Odometry
from fsw.core.motion import motion_profile as mp
from fsw.core.motion import wheel_kinematics as wk

CFG = mp.MotionConfig()
WHEEL_XY = wk.wheel_positions(RoverConfig())


def test_goto_turns_drives_and_turns_or_backs_up() -> None:
    plan = mp.goto_plan((0.0, 0.0, 0.0), 0.0, 1.0, 0.0, 0.0, CFG)
    assert [k for k, _, _ in plan] == ["turn", "drive", "turn"]
    assert plan[0][1] == pytest.approx(math.pi / 2) and plan[1][1] == pytest.approx(1.0)
    assert plan[2][1] == pytest.approx(-math.pi / 2)
    assert plan[1][2] == CFG.drive_speed_mps  # speed 0: the default
    back = mp.goto_plan((0.0, 0.0, 0.0), -0.5, 0.0, None, 0.0, CFG)
    assert back == [("drive", pytest.approx(-0.5), CFG.drive_speed_mps)]  # backs up, no U-turn
    assert mp.goto_plan((1.0, 1.0, 0.3), 1.0 + CFG.position_tolerance_m / 2, 1.0, None, 0.0, CFG) == []


def test_trapezoid_ramps_up_cruises_and_ramps_down_to_arrive() -> None:
    """A 1 m drive at 0.15 m/s, 0.2 m/s^2, 10 Hz, integrated with the speeds the profile gives."""
    seg = mp.Segment("drive", 1.0, 0.15, np.zeros(4), phase="move")
    x, dt, speeds = 0.0, 0.1, []
    for _ in range(400):
        rem, tol, acc, vmin = mp.remaining(seg, (x, 0.0, 0.0), 0.0, CFG, WHEEL_XY)
        if mp.arrived(seg, rem, tol):
            break
        v = mp.ramp_speed(seg, rem, acc, vmin, dt)
        speeds.append(v)
        x += math.copysign(v, rem) * dt
    else:
        pytest.fail("the drive never arrived")
    assert abs(x - 1.0) <= CFG.position_tolerance_m + CFG.min_speed_mps * dt
    steps = np.diff(speeds)
    assert steps.max() <= CFG.accel_mps2 * dt + 1e-12  # never accelerates harder than configured
    assert max(speeds) == pytest.approx(0.15)  # cruises at the limit
    assert min(speeds) >= CFG.min_speed_mps  # never below the creep speed
    assert speeds[0] == pytest.approx(CFG.accel_mps2 * dt)  # starts from rest


def test_turn_progress_is_the_accumulated_yaw() -> None:
    seg = mp.Segment("turn", -0.5, 0.2, np.zeros(4), phase="move", yaw_acc0=1.0)
    rem, tol, _, vmin = mp.remaining(seg, (0.0, 0.0, 0.0), 0.8, CFG, WHEEL_XY)
    assert rem == pytest.approx(-0.3) and tol == pytest.approx(math.radians(CFG.yaw_tolerance_deg))
    assert vmin == pytest.approx(CFG.min_speed_mps / float(np.hypot(*WHEEL_XY[0])))
    assert not mp.arrived(seg, rem, tol) and mp.arrived(seg, -tol / 2, tol)


def test_odometry_integrates_a_straight_drive_and_grows_its_covariance() -> None:
    r = 0.1
    odo = Odometry(r, wk.body_motion_matrix(WHEEL_XY))
    steer = np.zeros(4)
    for k in range(11):  # ten steps of 0.05 rad of every drive wheel: 10 * 0.005 m
        odo.update(np.full(4, 0.05 * k), steer)
    assert odo.pose[0] == pytest.approx(0.05) and abs(odo.pose[1]) < 1e-12 and abs(odo.pose[2]) < 1e-12
    assert odo.path_m == pytest.approx(0.05) and odo.turned_rad == pytest.approx(0.0, abs=1e-12)
    cov = odo.covariance(CFG)
    k, L = CFG.odo_sigma_per_m, 0.05  # growth per metre, and the heading error carried over L
    assert math.sqrt(cov[0, 0]) == pytest.approx(k * L + k * L * L / 2, rel=5e-3)  # the integral in 10 steps
    odo.reset((1.0, 2.0, 0.5))
    assert odo.pose == (1.0, 2.0, 0.5) and odo.path_m == 0.0 and odo.covariance(CFG)[0, 0] == 0.0
