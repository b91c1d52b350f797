"""Rover and mast truth models and the wheel kinematics they share with odometry (issue 3, item 4)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hil_helpers import cfg

from fsw.core.motion import wheel_kinematics as wk
from hil_sim.mast_truth import MastTruth, MastTruthConfig
from hil_sim.rover_truth import FlatTerrain, RoverTruth, RoverTruthConfig

EXACT = RoverTruthConfig(slip_mean=0.0, slip_bias_sigma=0.0, slip_noise_sigma=0.0, steer_offset_sigma_deg=0.0)


class Slope:
    """A 10 % grade rising along +x."""

    def height_at(self, x, y):  # type: ignore[no-untyped-def]
        return 0.1 * np.asarray(x, float) + 0.0 * np.asarray(y, float)


def test_wheel_commands_and_odometry_are_inverse() -> None:
    xy = wk.wheel_positions(cfg().rover)
    pinv = wk.body_motion_matrix(xy)
    for twist in [(0.2, 0.0, 0.0), (0.0, 0.0, 0.3), (0.1, 0.05, 0.1), (-0.15, 0.0, -0.2)]:
        steer, rate = wk.wheel_commands(*twist, xy, 0.1)
        assert np.all(np.abs(steer) <= math.pi / 2 + 1e-12)
        assert wk.body_motion(rate * 0.1, steer, pinv) == pytest.approx(np.array(twist), abs=1e-9)


def test_straight_drive_loses_the_slip_and_odometry_drifts() -> None:
    rover = cfg().rover
    exact = RoverTruth(FlatTerrain(), rover, EXACT, 0)
    slipping = RoverTruth(FlatTerrain(), rover, RoverTruthConfig(slip_noise_sigma=0.0, slip_bias_sigma=0.0), 0)
    for r in (exact, slipping):
        r.omega_cmd[:] = 2.0
        r.step(10.0)
    ideal = 0.1 * exact.drive_angle.mean()  # what wheel odometry says
    assert exact.x == pytest.approx(ideal, rel=1e-6) and slipping.x == pytest.approx(0.98 * ideal, rel=1e-3)


def test_turn_in_place_and_steer_rate_limit() -> None:
    xy = wk.wheel_positions(cfg().rover)
    steer, rate = wk.wheel_commands(0.0, 0.0, 0.2, xy, 0.1)
    r = RoverTruth(FlatTerrain(), cfg().rover, EXACT, 0)
    r.steer_cmd[:] = steer
    r.step(0.1)
    assert np.all(np.abs(r.steer) <= math.radians(90.0) * 0.1 + 1e-9)  # 90 deg/s slew
    r.step(2.0)
    r.omega_cmd[:] = rate
    r.step(5.0)
    assert math.hypot(r.x, r.y) < 1e-6 and r.yaw == pytest.approx(1.0, abs=0.05)  # 0.2 rad/s for 5 s, less the spin-up


def test_terrain_sets_pitch_and_height() -> None:
    r = RoverTruth(Slope(), cfg().rover, EXACT, 0, start=(1.0, 0.0, 0.0))
    assert math.degrees(r.pitch) == pytest.approx(math.degrees(math.atan(0.1)), abs=0.01)
    assert r.z == pytest.approx(0.1, abs=1e-6) and r.roll == pytest.approx(0.0, abs=1e-9)
    r2 = RoverTruth(Slope(), cfg().rover, EXACT, 0, start=(1.0, 0.0, math.pi / 2))
    assert math.degrees(r2.roll) == pytest.approx(-math.degrees(math.atan(0.1)), abs=0.01)  # left side downhill


def test_shoulders_move_the_wheels_and_the_body() -> None:
    r = RoverTruth(FlatTerrain(), cfg().rover, EXACT, 0)
    base, z0 = r.wheel_xy()[0, 0], r.z
    assert base == pytest.approx(0.35)
    r.shoulder_cmd[:] = math.radians(45)
    r.step(2.0)
    assert r.wheel_xy()[0, 0] > base and r.z < z0


def test_mast_slews_at_its_rates_and_stops_at_limits() -> None:
    m = cfg().mast
    mast = MastTruth(
        m, MastTruthConfig(pan_offset_sigma_deg=0.0, tilt_offset_sigma_deg=0.0, lift_offset_sigma_m=0.0), 0
    )
    mast.set_target(math.radians(200), math.radians(-80), 1.0)  # beyond every limit: clamped
    mast.step(1.0)
    assert math.degrees(mast.q[0]) == pytest.approx(m.pan_rate_dps, abs=1e-9)
    assert mast.q[2] == pytest.approx(m.lift_rate_mps, abs=1e-12) and mast.moving
    mast.step(20.0)
    assert math.degrees(mast.q[0]) == pytest.approx(m.pan_max_deg) and math.degrees(mast.q[1]) == pytest.approx(
        m.tilt_min_deg
    )
    assert mast.q[2] == pytest.approx(m.lift_max_m) and not mast.moving
    mast.stalled = True
    mast.set_target(0.0, 0.0, 0.0)
    mast.step(1.0)
    assert math.degrees(mast.q[0]) == pytest.approx(m.pan_max_deg)


def test_truth_is_repeatable_for_a_seed() -> None:
    def run(seed: int) -> tuple[float, float, float]:
        r = RoverTruth(FlatTerrain(), cfg().rover, RoverTruthConfig(), seed)
        r.omega_cmd[:] = 1.5
        r.step(5.0)
        return r.pose

    assert run(3) == run(3) and run(3) != run(4)
