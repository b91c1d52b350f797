"""The rover attitude sensor's CAN frame, sans I/O: ``IMU_ATTITUDE`` of ``config/rover.dbc``.

Both ends use it: the flight driver (``fsw.drivers.imu_can``) and the emulated sensor of the
bench (``hil_sim.hw.imu``). The frame carries the body roll and pitch (ALGORITHM.md §5.1: the
accelerometer's gravity direction), the gyro yaw rate and two flags; it ends with
``IMU_ATTITUDE_Counter`` (4-bit alive counter) and ``IMU_ATTITUDE_CRC``, the same
CRC-8/SAE-J1850 end-to-end checksum as the motor frames (``fsw.comm.rover_can.e2e_checksum``:
over the frame id and every data byte but the last).

:meth:`ImuCan.decode` never raises on bad input: it returns a ``Bad`` with the reason.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import cantools

from fsw.comm.rover_can import DEFAULT_DBC, Bad, e2e_checksum

MSG = "IMU_ATTITUDE"
COUNTER = f"{MSG}_Counter"
CRC = f"{MSG}_CRC"


@dataclass(frozen=True)
class ImuAttitude:
    """A decoded ``IMU_ATTITUDE``: body roll (left side up +) and pitch (nose up +), degrees."""

    roll_deg: float
    pitch_deg: float
    yaw_rate_dps: float
    self_test_fail: bool
    moving: bool
    counter: int


class ImuCan:
    """Encoder/decoder of the attitude frame of the rover DBC."""

    def __init__(self, dbc_path: str | Path = DEFAULT_DBC) -> None:
        db = cantools.database.load_file(str(dbc_path))
        if not isinstance(db, cantools.database.can.Database):
            raise ValueError(f"{dbc_path}: not a CAN database")
        try:
            self.msg = db.get_message_by_name(MSG)
        except KeyError:
            raise ValueError(f"{dbc_path}: DBC lacks frame {MSG}") from None
        names = {s.name for s in self.msg.signals}
        if not {"Roll", "Pitch", COUNTER, CRC} <= names:
            raise ValueError(f"{dbc_path}: {MSG} lacks Roll, Pitch, {COUNTER} or {CRC}")
        self.frame_id = int(self.msg.frame_id)

    def encode(self, roll_deg: float, pitch_deg: float, yaw_rate_dps: float, self_test_fail: bool,
               moving: bool, counter: int) -> tuple[int, bytes]:
        """One protected frame; out-of-range or non-finite values are clipped / zeroed."""

        def fin(v: float, lim: float) -> float:
            return max(-lim, min(lim, float(v))) if math.isfinite(v) else 0.0

        data = bytearray(self.msg.encode({
            "Roll": fin(roll_deg, 180.0), "Pitch": fin(pitch_deg, 90.0),
            "YawRate": fin(yaw_rate_dps, 204.7), "SelfTestFail": int(self_test_fail),
            "Moving": int(moving), COUNTER: counter & 0xF, CRC: 0,
        }, strict=False))
        data[-1] = e2e_checksum(self.frame_id, bytes(data))
        return self.frame_id, bytes(data)

    def decode(self, frame_id: int, data: bytes, is_extended: bool = False) -> ImuAttitude | Bad:
        """Decode one received frame; never raises on bad input."""
        if is_extended or frame_id != self.frame_id:
            return Bad(frame_id, "unknown_id", f"id 0x{frame_id:03X} is not {MSG}")
        if len(data) != self.msg.length:
            return Bad(frame_id, "dlc", f"{MSG}: {len(data)} bytes, expected {self.msg.length}")
        want = e2e_checksum(frame_id, data)
        if data[-1] != want:
            return Bad(frame_id, "checksum", f"{MSG}: checksum 0x{data[-1]:02X} != 0x{want:02X}")
        try:
            s = cast(dict[str, Any], self.msg.decode(bytes(data), decode_choices=False, scaling=True))
        except Exception as exc:  # noqa: BLE001 - cantools errors vary by version; a bad frame is data
            return Bad(frame_id, "decode", f"{MSG}: {exc}")
        return ImuAttitude(float(s["Roll"]), float(s["Pitch"]), float(s["YawRate"]),
                           bool(s["SelfTestFail"]), bool(s["Moving"]), int(s[COUNTER]))
