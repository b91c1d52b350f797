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


class _EverySubstep(RoverTruth):
    """The reference: every sub-step integrated in full, never the rest shortcut."""

    def _rest_substeps(self, dt: float, n: int, motion: np.ndarray) -> None:
        for _ in range(n):
            self._substep(dt)


class _Counted(RoverTruth):
    shortcuts = 0

    def _rest_substeps(self, dt: float, n: int, motion: np.ndarray) -> None:
        self.shortcuts += 1
        super()._rest_substeps(dt, n, motion)


def _truth_state(r: RoverTruth) -> bytes:
    arrays = (r.omega, r.drive_angle, r.steer, r.shoulder, r.slip_noise, r.drive_current, r.steer_current,
              r.shoulder_current, np.array([r.x, r.y, r.yaw, r.z, r.pitch, r.roll, r.odometer_m]))
    return b"".join(np.asarray(a, float).tobytes() for a in arrays) + repr(r._rng.bit_generator.state).encode()


def test_the_rest_shortcut_gives_the_same_bits_as_every_substep() -> None:
    """At rest ``RoverTruth.step`` skips the sub-steps that change nothing but the slip noise
    and the pose; a seeded drive (moves, stops, steering and shoulders slewing, a stalled and a
    coasting wheel, negative zeros in the commands) stays bit-identical to integrating every sub-step."""
    rng = np.random.default_rng(7)
    fast = _Counted(Slope(), cfg().rover, RoverTruthConfig(), 4, start=(1.0, 0.5, 0.3))
    ref = _EverySubstep(Slope(), cfg().rover, RoverTruthConfig(), 4, start=(1.0, 0.5, 0.3))
    for k in range(120):
        phase = k % 12
        for r in (fast, ref):
            r.stalled[:] = [k in (24, 25), False, False, False]
            r.drive_fault[:] = [False, k in (36, 37, 38), False, False]
        drive = rng.uniform(1.5, 2.0) * rng.choice([-1.0, 1.0]) + rng.uniform(-0.1, 0.1, 4)
        cmd_omega = drive if phase < 4 else np.array([0.0, -0.0, 0.0, -0.0])
        cmd_steer = rng.uniform(-0.5, 0.5, 4) if phase == 5 else None
        cmd_shoulder = math.radians(30.0 + rng.uniform(-2.0, 2.0)) if phase == 7 else None
        for r in (fast, ref):
            r.omega_cmd[:] = cmd_omega
            if cmd_steer is not None:
                r.steer_cmd[:] = cmd_steer
            if cmd_shoulder is not None:
                r.shoulder_cmd[:] = cmd_shoulder
        draws = fast._rng.bit_generator.state["state"]["state"]
        fast.step(0.1)
        ref.step(0.1)
        assert _truth_state(fast) == _truth_state(ref), f"step {k}"
        assert fast._rng.bit_generator.state["state"]["state"] != draws  # the slip noise drew every step
    assert 30 < fast.shortcuts < 120 and fast.odometer_m > 0.1  # both regimes were exercised
