"""True motion of the SRR-like rover over the terrain (the physics behind the motor controllers).

Four wheels, each with a drive motor, a steer motor and a shoulder joint (JPL's Sample Return
Rover). Actuators follow their set-points within rate and acceleration limits; the body moves
by the least-squares rigid motion of the four wheel contacts (``fsw.core.motion.wheel_kinematics``),
so inconsistent steering scrubs instead of breaking the model. The terrain comes from
``World.height_at``: the body settles on the four contact heights (height, pitch, roll).

Actuation error, seeded: every wheel slips (a per-wheel bias plus a correlated fluctuation
around ``slip_mean``) and every steer joint has a small calibration offset, so dead reckoning
from the encoders drifts from this truth. A wheel whose contact point lies off the world's
terrain is flagged (``wheels_off``; the bench reports it as a fault), never given invented
ground silently. The shoulders change where the wheels touch (the
wheelbase) and the body height. No bytes here: :mod:`hil_sim.hw.motor_controllers` reads and
drives this model.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from fsw.core.geometry import RoverConfig, body_rotation
from fsw.core.motion.wheel_kinematics import body_motion, body_motion_matrix, integrate_pose
from fsw.framework.params import param

F64 = NDArray[np.float64]


class Terrain(Protocol):
    def height_at(self, x: F64 | float, y: F64 | float) -> F64: ...


class FlatTerrain:
    """Level ground at ``z_m`` (when no world is given)."""

    def __init__(self, z_m: float = 0.0) -> None:
        self.z_m = z_m

    def height_at(self, x: F64 | float, y: F64 | float) -> F64:
        return np.full(np.broadcast(np.asarray(x), np.asarray(y)).shape, self.z_m, dtype=float)


@dataclass(frozen=True)
class RoverTruthConfig:
    """Actuator limits, leg geometry and the seeded actuation error of the true rover."""

    wheel_accel_radps2: float = param(4.0, lo=0.1, hi=100.0, units="rad/s^2")
    coast_time_s: float = param(0.3, lo=0.01, hi=10.0, units="s", doc="spin-down of a faulted drive")
    steer_rate_dps: float = param(90.0, lo=1.0, hi=720.0, units="deg/s")
    steer_stop_deg: float = param(100.0, lo=10.0, hi=180.0, units="deg", doc="mechanical steer stop")
    shoulder_rate_dps: float = param(15.0, lo=0.1, hi=360.0, units="deg/s")
    shoulder_min_deg: float = param(0.0, lo=-90.0, hi=90.0, units="deg", doc="mechanical shoulder stop")
    shoulder_max_deg: float = param(60.0, lo=-90.0, hi=90.0, units="deg")
    shoulder_nominal_deg: float = param(
        30.0, lo=-90.0, hi=90.0, units="deg", doc="leg angle from vertical at which the wheels sit at +-wheelbase/2"
    )
    leg_length_m: float = param(0.4, lo=0.05, hi=2.0, units="m", doc="shoulder to wheel axle")
    slip_mean: float = param(0.02, lo=-0.5, hi=0.9, doc="mean longitudinal slip (fraction of the rolled distance lost)")
    slip_bias_sigma: float = param(0.01, lo=0.0, hi=0.5, doc="per-wheel constant slip spread")
    slip_noise_sigma: float = param(0.02, lo=0.0, hi=0.5, doc="slip fluctuation (AR(1) standard deviation)")
    slip_corr_time_s: float = param(1.0, lo=0.01, hi=100.0, units="s")
    steer_offset_sigma_deg: float = param(0.5, lo=0.0, hi=10.0, units="deg", doc="steer calibration error")
    substep_s: float = param(0.01, lo=0.001, hi=0.1, units="s", doc="integration step")
    current_idle_a: float = param(0.3, lo=0.0, hi=10.0, units="A")
    current_per_radps_a: float = param(0.4, lo=0.0, hi=10.0, units="A/(rad/s)")
    current_per_radps2_a: float = param(0.5, lo=0.0, hi=10.0, units="A/(rad/s^2)")
    current_per_grade_a: float = param(6.0, lo=0.0, hi=100.0, units="A", doc="extra drive current on a 100% grade")
    stall_current_a: float = param(12.0, lo=0.0, hi=12.7, units="A", doc="current of a stalled drive")


class RoverTruth:
    """State and integration of the true rover; wheel arrays are ordered FL, FR, RL, RR."""

    def __init__(
        self,
        terrain: Terrain,
        rover: RoverConfig,
        cfg: RoverTruthConfig,
        seed: int,
        start: tuple[float, float, float] = (0.0, 0.0, 0.0),
    ) -> None:
        self.terrain, self.rover, self.cfg = terrain, rover, cfg
        self.r = rover.wheel_diameter_m / 2.0
        rng = np.random.default_rng(seed)
        self._rng = rng
        self.x, self.y, self.yaw = (float(v) for v in start)
        nom = math.radians(cfg.shoulder_nominal_deg)
        self._hip_x = rover.wheelbase_m / 2.0 - cfg.leg_length_m * math.sin(nom)
        self._sign_x = np.array([1.0, 1.0, -1.0, -1.0])
        self._half_track = np.array([1.0, -1.0, 1.0, -1.0]) * rover.track_m / 2.0
        self.omega = np.zeros(4)  # drive rates, rad/s
        self.drive_angle = np.zeros(4)  # drive encoders, rad
        self.steer = np.zeros(4)  # rad (encoder reading; the wheel points at steer + offset)
        self.shoulder = np.full(4, nom)
        self.omega_cmd = np.zeros(4)
        self.steer_cmd = np.zeros(4)
        self.shoulder_cmd = self.shoulder.copy()
        self.drive_fault = np.zeros(4, bool)  # coasting (controller disabled or driver fault)
        self.stalled = np.zeros(4, bool)  # mechanically blocked wheel (fault injection)
        self.steer_offset = np.radians(rng.normal(0.0, cfg.steer_offset_sigma_deg, 4))
        self.slip_bias = rng.normal(0.0, cfg.slip_bias_sigma, 4)
        self.slip_noise = np.zeros(4)
        self.drive_current = np.full(4, cfg.current_idle_a)
        self.steer_current = np.zeros(4)
        self.shoulder_current = np.zeros(4)
        self.z = self.pitch = self.roll = 0.0
        self.odometer_m = 0.0
        self.max_wheel_drop_m = 0.0
        self.wheels_off = np.zeros(4, bool)  # wheels with no terrain under them (off the world)
        self._pinv_key: np.ndarray | None = None
        self._pinv = np.zeros((3, 8))
        self._settle()

    # -- set-points (from the motor controllers) -------------------------------------------------
    def wheel_xy(self) -> F64:
        """(4, 2) wheel contacts in the body frame for the current shoulder angles."""
        x = self._sign_x * (self._hip_x + self.cfg.leg_length_m * np.sin(self.shoulder))
        return np.column_stack([x, self._half_track])

    # -- integration ------------------------------------------------------------------------
    def step(self, dt_s: float) -> None:
        """Advance ``dt_s`` seconds in sub-steps of at most ``substep_s``.

        At rest (no drive commanded or turning, and a sub-step that left the actuators and
        encoders exactly as they were) the remaining sub-steps are :meth:`_rest_substeps`: the
        same arithmetic on what still changes (the slip noise's random draws, the pose), so the
        result is bit for bit that of full sub-steps."""
        n = max(1, math.ceil(dt_s / self.cfg.substep_s - 1e-9))
        dt = dt_s / n
        for i in range(n):
            resting = not self.omega_cmd.any() and not self.omega.any()
            before = self._actuator_bytes() if resting else b""
            motion = self._substep(dt)
            if resting and i + 1 < n and not self.omega.any() and self._actuator_bytes() == before:
                self._rest_substeps(dt, n - i - 1, motion)
                break
        self._settle()  # terrain contact once per step: the body moves millimetres per sub-step

    def _actuator_bytes(self) -> bytes:
        return b"".join(a.tobytes() for a in (self.omega, self.steer, self.shoulder, self.drive_angle))

    def _rest_substeps(self, dt: float, n: int, motion: F64) -> None:
        """``n`` sub-steps of a rover at rest whose last sub-step was a fixed point of the
        actuators and encoders: those and the currents stay as they are, every wheel rolls an
        exact zero (so ``motion`` repeats), and only the slip noise (``n`` draws of four, the
        generator's stream as in :meth:`_substep`) and the pose integration advance."""
        c = self.cfg
        a = math.exp(-dt / c.slip_corr_time_s)
        noise = c.slip_noise_sigma * math.sqrt(1 - a * a) * self._rng.standard_normal((n, 4))
        pose = (self.x, self.y, self.yaw)
        step_m = math.hypot(float(motion[0]), float(motion[1]))
        for k in range(n):
            self.slip_noise = a * self.slip_noise + noise[k]
            pose = integrate_pose(pose, motion)
            self.odometer_m += step_m
        self.x, self.y, self.yaw = pose

    def _substep(self, dt: float) -> F64:
        c = self.cfg
        prev = self.omega.copy()
        accel = np.clip(self.omega_cmd - self.omega, -c.wheel_accel_radps2 * dt, c.wheel_accel_radps2 * dt)
        coast = self.omega * math.exp(-dt / c.coast_time_s)
        self.omega = np.where(self.drive_fault, coast, self.omega + accel)
        self.omega = np.where(self.stalled, 0.0, self.omega)
        ds = math.radians(c.steer_rate_dps) * dt
        stop = math.radians(c.steer_stop_deg)
        steer_step = np.clip(self.steer_cmd - self.steer, -ds, ds)
        self.steer = np.clip(self.steer + steer_step, -stop, stop)
        dsh = math.radians(c.shoulder_rate_dps) * dt
        sh_step = np.clip(self.shoulder_cmd - self.shoulder, -dsh, dsh)
        self.shoulder = np.clip(
            self.shoulder + sh_step, math.radians(c.shoulder_min_deg), math.radians(c.shoulder_max_deg)
        )
        # slip: per-wheel bias + AR(1) fluctuation
        a = math.exp(-dt / c.slip_corr_time_s)
        self.slip_noise = a * self.slip_noise + c.slip_noise_sigma * math.sqrt(1 - a * a) * self._rng.standard_normal(4)
        slip = np.clip(c.slip_mean + self.slip_bias + self.slip_noise, -0.2, 0.9)
        roll = self.omega * self.r * dt * (1.0 - slip) * math.cos(self.pitch)
        if self._pinv_key is None or not np.array_equal(self._pinv_key, self.shoulder):
            self._pinv_key, self._pinv = self.shoulder.copy(), body_motion_matrix(self.wheel_xy())
        motion = body_motion(roll, self.steer + self.steer_offset, self._pinv)
        self.x, self.y, self.yaw = integrate_pose((self.x, self.y, self.yaw), motion)
        self.odometer_m += math.hypot(float(motion[0]), float(motion[1]))
        self.drive_angle += self.omega * dt
        alpha = np.abs(self.omega - prev) / dt
        grade = abs(math.tan(self.pitch))
        self.drive_current = (
            c.current_idle_a
            + c.current_per_radps_a * np.abs(self.omega)
            + c.current_per_radps2_a * alpha
            + c.current_per_grade_a * grade * (np.abs(self.omega) > 0)
        )
        self.drive_current = np.where(
            self.stalled & (np.abs(self.omega_cmd) > 0), c.stall_current_a, self.drive_current
        )
        self.steer_current = np.where(np.abs(steer_step) > 1e-9, 1.7, 0.2)  # slewing vs holding, A
        self.shoulder_current = np.where(np.abs(sh_step) > 1e-9, 2.5, 0.5)
        return motion

    def _settle(self) -> None:
        """Body height, pitch and roll from the terrain under the four wheels."""
        wx, wy = self.world_wheel_xy()
        h = np.asarray(self.terrain.height_at(wx, wy), dtype=float)
        # A wheel off the world's terrain has no ground: a bench fault (HardwareRig reports
        # it); the body rests on the wheels that do have ground.
        self.wheels_off = ~np.isfinite(h)
        h = np.where(np.isfinite(h), h, np.nanmin(h) if np.isfinite(h).any() else 0.0)
        legs = self.cfg.leg_length_m * np.cos(self.shoulder)
        hip = h + legs  # hip height above the world datum (axle heights cancel out)
        nominal = self.cfg.leg_length_m * math.cos(math.radians(self.cfg.shoulder_nominal_deg))
        xy = self.wheel_xy()
        span = float(xy[0, 0] - xy[2, 0]) or 1e-9
        self.pitch = math.atan2(float(hip[:2].mean() - hip[2:].mean()), span)
        self.roll = math.atan2(float(hip[[0, 2]].mean() - hip[[1, 3]].mean()), self.rover.track_m)
        self.z = float(hip.mean() - nominal)
        self.max_wheel_drop_m = max(self.max_wheel_drop_m, float(h.max() - h.min()))

    def world_wheel_xy(self) -> tuple[F64, F64]:
        xy = self.wheel_xy()
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return self.x + c * xy[:, 0] - s * xy[:, 1], self.y + s * xy[:, 0] + c * xy[:, 1]

    def body_rotation(self) -> F64:
        """Body-to-world rotation: yaw about z, then pitch (nose up +), then roll (left side up +)
        (``fsw.core.geometry.body_rotation``, the flight software's convention)."""
        return body_rotation(self.yaw, self.pitch, self.roll)

    @property
    def pose(self) -> tuple[float, float, float]:
        return (self.x, self.y, self.yaw)
