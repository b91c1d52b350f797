"""Emulated inclinometer/IMU: the CAN end of the rover's attitude sensor (docs/algorithm.md §5.1).

Every ``period_s`` it sends ``IMU_ATTITUDE`` (``config/rover.dbc``, :mod:`fsw.comm.imu_can`):
the true body roll and pitch of :class:`hil_sim.rover_truth.RoverTruth` (the attitude the
terrain under the four wheels gives it) plus, per axis, a constant bias drawn once from the
seed (``bias_sigma_deg``: the sensor's mounting and offset error) and white noise per sample
(``noise_sigma_deg``), quantised by the frame's 0.01 deg; the yaw rate is the true one with
noise. Seeded (``seed``), so a lockstep run repeats.

Faults (``hil_sim.faults``, kind ``imu_fault``): ``mode = "stuck"`` repeats the last frame
byte for byte (a hung sensor: the alive counter stops), ``mode = "dropout"`` (or no mode)
sends nothing, ``mode = "selftest"`` sets the SelfTestFail flag. The frames also cross the
CAN faults (drop, delay, corrupt) of target ``IMU``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import can
import numpy as np

from fsw.comm.imu_can import ImuCan
from fsw.framework.params import param
from hil_sim.faults import FaultInjector
from hil_sim.rover_truth import RoverTruth


@dataclass(frozen=True)
class ImuConfig:
    """The emulated attitude sensor (``[imu]`` of ``config/hil_hardware.toml``)."""

    period_s: float = param(0.05, lo=0.005, hi=10.0, units="s", doc="IMU_ATTITUDE frame period")
    bias_sigma_deg: float = param(0.1, lo=0.0, hi=10.0, units="deg", doc="per-axis constant bias (seeded)")
    noise_sigma_deg: float = param(0.05, lo=0.0, hi=10.0, units="deg", doc="white noise per sample")
    yaw_rate_noise_dps: float = param(0.1, lo=0.0, hi=50.0, units="deg/s")


class ImuDevice:
    """Sends the rover's attitude as the sensor would, through the fault injector."""

    def __init__(self, bus: can.BusABC, codec: ImuCan, rover: RoverTruth, cfg: ImuConfig, seed: int,
                 faults: FaultInjector | None = None) -> None:
        self.bus, self.codec, self.rover, self.cfg = bus, codec, rover, cfg
        self.faults = faults or FaultInjector()
        self.rng = np.random.default_rng([seed, codec.frame_id])  # its own stream, not another device's
        self.bias_deg = self.rng.normal(0.0, cfg.bias_sigma_deg, 2)  # roll, pitch
        self.counter = 0
        self._t_sent = -math.inf
        self._last: bytes | None = None
        self._yaw_prev: float | None = None
        self.tx_frames = 0

    def transmit(self, now: float) -> None:
        """Send a frame when one is due (nothing while bus-off or in a dropout)."""
        if now - self._t_sent < self.cfg.period_s - 1e-9:
            return
        dt = now - self._t_sent if math.isfinite(self._t_sent) else 0.0
        self._t_sent = now
        r = self.rover
        yaw_rate = 0.0 if self._yaw_prev is None or dt <= 0 else math.degrees(
            math.remainder(r.yaw - self._yaw_prev, math.tau)) / dt
        self._yaw_prev = r.yaw
        mode = self.faults.imu_fault()
        if self.faults.bus_off() or mode == "dropout":
            return
        if mode == "stuck" and self._last is not None:
            self._emit(self._last, now)
            return
        noise = self.rng.normal(0.0, self.cfg.noise_sigma_deg, 2)
        self.counter += 1  # full alive counter (E2E freshness)
        _, data = self.codec.encode(
            math.degrees(r.roll) + self.bias_deg[0] + noise[0],
            math.degrees(r.pitch) + self.bias_deg[1] + noise[1],
            yaw_rate + self.rng.normal(0.0, self.cfg.yaw_rate_noise_dps),
            mode == "selftest", bool(np.any(np.abs(r.omega) > 1e-3)), self.counter)
        self._last = data
        self._emit(data, now)

    def _emit(self, data: bytes, now: float) -> None:
        fate, data, _delay = self.faults.can_frame("IMU", True, data)  # delay: treated as a loss here
        if fate == "drop" or _delay:
            return
        msg = can.Message(arbitration_id=self.codec.frame_id, data=data, is_extended_id=False, timestamp=now)
        try:
            self.bus.send(msg)
            self.tx_frames += 1
        except can.CanError:
            pass  # a full or closed bus loses the frame, as on a real wire
