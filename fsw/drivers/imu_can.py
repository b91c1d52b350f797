"""Flight driver of the rover's attitude sensor (inclinometer/IMU) on the rover CAN bus.

The sensor shares the motor bus: the motor driver (``fsw.drivers.can_motors``) drains the
bus and hands every ``IMU_ATTITUDE`` frame to this driver (``CanMotorDriver.listeners``), so
one bus handle serves both, on the rover (socketcan) as on the bench (virtual, udp_hub).

* Each frame is checked end to end (:mod:`fsw.comm.imu_can`: length, reserved bits, then
  counter and CRC-8 under the frame's freshness, :class:`fsw.comm.e2e.SequenceChecker`): a bad,
  stale or replayed frame is refused and counted; a counter jump (up to ``MAX_DELTA``) counts
  lost frames; a counter that stops advancing for ``stuck_frames`` frames is a STUCK sensor (a
  hung device repeating its buffer); no valid frame for ``timeout_s`` is a TIMEOUT (dropout, cable); a SelfTestFail
  flag is a SELF_TEST fault. Each finding is a fault bit and an event.
* :meth:`attitude` gives the body roll and pitch (docs/algorithm.md §5.1: the gravity direction at
  rest) as the mean of the fresh samples of the last ``average_s`` and its covariance: the
  sensor's stated bias variance (``sigma_deg``, from its calibration) plus the sample
  variance over the number of samples. While any fault is set it returns None: the caller
  must then treat the attitude as unknown (``fsw.core.localization.attitude``), never as level.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import ClassVar, Protocol

import numpy as np
from numpy.typing import NDArray

from fsw.comm.e2e import Seq, SequenceChecker
from fsw.comm.imu_can import ImuAttitude, ImuCan
from fsw.drivers.base import DriverBase
from fsw.framework.telemetry import EventDef, Severity

F_BAD_FRAMES, F_TIMEOUT, F_STUCK, F_SELF_TEST, F_LOST_FRAMES = 0x01, 0x02, 0x04, 0x08, 0x10
MAX_DELTA = 4  # largest counter jump taken (3 frames lost); above 4 a 1-3 bit error could cross an epoch
#: faults that make the attitude unusable (bad or lost frames alone only degrade)
UNUSABLE = F_TIMEOUT | F_STUCK | F_SELF_TEST

# what an attitude is computed from: (time, unusable faults, frames received, samples, the last sample)
_AttitudeKey = tuple[float, int, int, int, tuple[float, float, float] | None]


class FrameOwner(Protocol):
    """The driver that owns the CAN bus (``fsw.drivers.can_motors``): frame id -> listener."""

    listeners: dict[int, Callable[[bytes, float], None]]


@dataclass(frozen=True)
class Attitude:
    """Body roll and pitch (rad) with their 2x2 covariance (rad^2) from ``samples`` frames."""

    roll: float
    pitch: float
    cov: NDArray[np.float64]
    samples: int
    time_s: float


class ImuDriver(DriverBase):
    """Supervision and averaging of the ``IMU_ATTITUDE`` frames the motor driver passes on."""

    FAULTS: ClassVar[dict[str, int]] = {
        "bad_frames": F_BAD_FRAMES, "timeout": F_TIMEOUT, "stuck": F_STUCK,
        "self_test": F_SELF_TEST, "lost_frames": F_LOST_FRAMES,
    }
    EVENTS: ClassVar[tuple[EventDef, ...]] = (
        EventDef("IMU_BAD_FRAME", Severity.WARNING_LO, "IMU frame refused ({reason}): {detail}", throttle=5),
        EventDef("IMU_FRAMES_LOST", Severity.WARNING_LO, "IMU: {lost} frame(s) lost", throttle=5),
        EventDef("IMU_TIMEOUT", Severity.WARNING_HI, "IMU: no valid frame for {age_s:.2f} s; attitude unknown"),
        EventDef("IMU_STUCK", Severity.WARNING_HI, "IMU: alive counter stuck at {counter} for {frames} frames"),
        EventDef("IMU_SELF_TEST", Severity.WARNING_HI, "IMU reports a failed self-test"),
        EventDef("IMU_RECOVERED", Severity.ACTIVITY_HI, "IMU attitude valid again"),
    )

    def __init__(self, codec: ImuCan, *, timeout_s: float = 0.5, stuck_frames: int = 5,
                 average_s: float = 1.0, sigma_deg: float = 0.1, error_hold_s: float = 2.0) -> None:
        super().__init__(error_hold_s)
        self.codec = codec
        self.timeout_s, self.stuck_frames, self.average_s = timeout_s, stuck_frames, average_s
        self.sigma_rad = math.radians(sigma_deg)
        self.samples: deque[tuple[float, float, float]] = deque(maxlen=4096)  # (t, roll, pitch) rad
        self.counter: int | None = None
        self.repeats = 0
        self._seq = SequenceChecker(MAX_DELTA, timeout_s)
        self.t_valid: float | None = None
        self.t_start: float | None = None
        self.rx_frames = self.rx_bad = self.rx_lost = 0
        self.last: ImuAttitude | None = None
        self._att: tuple[_AttitudeKey, Attitude | None] | None = None  # (inputs, estimate) of the last call

    def attach(self, motors: FrameOwner) -> None:
        """Receive ``IMU_ATTITUDE`` from the motor driver that owns the bus."""
        motors.listeners[self.codec.frame_id] = self.on_frame

    # -- reception --------------------------------------------------------------------------
    def on_frame(self, data: bytes, now: float) -> None:
        d = self.codec.decode(self.codec.frame_id, data, epoch=None)  # the checksum: with the freshness
        if not isinstance(d, ImuAttitude):
            self.rx_bad += 1
            self._hold(F_BAD_FRAMES, now)
            self._event("IMU_BAD_FRAME", reason=d.reason, detail=d.detail)
            return
        verdict, _lost = self._seq.check_frame(self.codec.e2e, bytes(data), now)
        repeat = self.counter is not None and d.counter == self.counter and verdict in (Seq.REPEATED, Seq.LEARNING)
        if not verdict.accepted and not repeat:
            self.rx_bad += 1
            self._hold(F_BAD_FRAMES, now)
            self._event("IMU_BAD_FRAME", reason=verdict.value, detail=f"counter {d.counter}")
            return
        if repeat:
            self.repeats += 1
            if self.repeats >= self.stuck_frames - 1 and not self.has(F_STUCK):
                self._set(F_STUCK)
                self.samples.clear()
                self._event("IMU_STUCK", counter=d.counter, frames=self.repeats + 1)
            return
        if self.counter is not None:
            lost = (d.counter - self.counter - 1) & 0xF
            if lost:
                self.rx_lost += lost
                self._hold(F_LOST_FRAMES, now)
                self._event("IMU_FRAMES_LOST", lost=lost)
        self.counter, self.repeats, self.last = d.counter, 0, d
        self.rx_frames += 1
        was_bad = self.faults & UNUSABLE
        if d.self_test_fail != self.has(F_SELF_TEST):
            self._set(F_SELF_TEST, d.self_test_fail)
            if d.self_test_fail:
                self._event("IMU_SELF_TEST")
        self._set(F_STUCK, False)
        self._set(F_TIMEOUT, False)
        self.t_valid = now
        if not d.self_test_fail:
            self.samples.append((now, math.radians(d.roll_deg), math.radians(d.pitch_deg)))
        while self.samples and now - self.samples[0][0] > self.average_s:
            self.samples.popleft()
        if was_bad and not self.faults & UNUSABLE:
            self._event("IMU_RECOVERED")

    def poll(self, now: float) -> None:
        """Supervise (timeout, held bits); the frames arrive through the motor driver's poll."""
        self.last_poll_s = now
        if self.t_start is None:
            self.t_start = now
        self._expire_holds(now)
        age = now - (self.t_valid if self.t_valid is not None else self.t_start)
        if age > self.timeout_s and not self.has(F_TIMEOUT):
            self._set(F_TIMEOUT)
            self.samples.clear()
            self._event("IMU_TIMEOUT", age_s=age)

    # -- the estimate -----------------------------------------------------------------------
    def attitude(self, now: float) -> Attitude | None:
        """Mean roll and pitch of the last ``average_s`` with covariance; None when unusable.
        Computed once per frame: the device component and the motion task both ask (the same
        object is returned while the time, the samples and the fault word are the same)."""
        s = self.samples
        key = (now, self.faults & UNUSABLE, self.rx_frames, len(s), s[-1] if s else None)
        if self._att is not None and self._att[0] == key:
            return self._att[1]
        att = self._attitude(now)
        self._att = (key, att)
        return att

    def _attitude(self, now: float) -> Attitude | None:
        if self.faults & UNUSABLE:
            return None
        fresh = [s for s in self.samples if now - s[0] <= self.average_s]
        if not fresh:
            return None
        # mean and sample variance of ~10 samples in plain floats: numpy's call overhead was
        # 40 us a frame; the sums run in sample order as numpy's axis-0 reduction does, so the
        # values are numpy's to the bit (tests/fsw/drivers/test_imu.py)
        n = len(fresh)
        sr = sp = 0.0
        for _, r, p in fresh:
            sr += r
            sp += p
        mr, mp = sr / n, sp / n
        s2 = self.sigma_rad**2
        if n > 1:
            vr = vp = 0.0
            for _, r, p in fresh:
                vr += (r - mr) * (r - mr)
                vp += (p - mp) * (p - mp)
            var_r, var_p = vr / (n - 1) / n, vp / (n - 1) / n
        else:
            var_r = var_p = s2
        cov = np.array([[s2 + var_r, 0.0], [0.0, s2 + var_p]])
        return Attitude(mr, mp, cov, n, now)

    def close(self) -> None:
        """Nothing to release: the motor driver owns the bus."""
