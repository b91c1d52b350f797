"""The rover attitude sensor's CAN frame, sans I/O: ``IMU_ATTITUDE`` of ``config/rover.dbc``.

Both ends use it: the flight driver (``fsw.drivers.imu_can``) and the emulated sensor of the
bench (``hil_sim.hw.imu``). The frame carries the body roll and pitch (docs/algorithm.md §5.1: the
accelerometer's gravity direction), the gyro yaw rate and two flags; it ends with
``Counter`` (4-bit alive counter) and ``Checksum``, protected like every frame of the DBC
(``fsw.comm.e2e``: CRC-8/AUTOSAR over the data id and the payload XOR the counter's epoch,
reserved bits zero).

:meth:`ImuCan.decode` never raises on bad input: it returns a ``Bad`` with the reason.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import cantools

from fsw.comm.can_codec import CompiledMessage
from fsw.comm.e2e import CHECKSUM as CRC
from fsw.comm.e2e import COUNTER, E2ELayout
from fsw.comm.rover_can import DEFAULT_DBC, Bad

MSG = "IMU_ATTITUDE"


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

    def __init__(self, dbc_path: str | Path = DEFAULT_DBC, db: cantools.database.can.Database | None = None) -> None:
        """From the DBC file, or from an already loaded database ``db``."""
        if db is None:
            loaded = cantools.database.load_file(str(dbc_path))
            if not isinstance(loaded, cantools.database.can.Database):
                raise ValueError(f"{dbc_path}: not a CAN database")
            db = loaded
        try:
            self.msg = db.get_message_by_name(MSG)
        except KeyError:
            raise ValueError(f"{dbc_path}: DBC lacks frame {MSG}") from None
        names = {s.name for s in self.msg.signals}
        if not {"Roll", "Pitch", COUNTER, CRC} <= names:
            raise ValueError(f"{dbc_path}: {MSG} lacks Roll, Pitch, {COUNTER} or {CRC}")
        self.frame_id = int(self.msg.frame_id)
        self.e2e = E2ELayout.from_message(self.msg)
        self.codec = CompiledMessage(self.msg)  # compiled once: no cantools per frame

    def encode(self, roll_deg: float, pitch_deg: float, yaw_rate_dps: float, self_test_fail: bool,
               moving: bool, counter: int) -> tuple[int, bytes]:
        """One protected frame; out-of-range or non-finite values are clipped / zeroed."""

        def fin(v: float, lim: float) -> float:
            return max(-lim, min(lim, float(v))) if math.isfinite(v) else 0.0

        data = bytearray(self.codec.encode({
            "Roll": fin(roll_deg, 180.0), "Pitch": fin(pitch_deg, 90.0),
            "YawRate": fin(yaw_rate_dps, 204.7), "SelfTestFail": int(self_test_fail),
            "Moving": int(moving), COUNTER: counter & 0xF, CRC: 0,
        }))
        return self.frame_id, self.e2e.protect(bytes(data), counter)

    def decode(self, frame_id: int, data: bytes, is_extended: bool = False,
               epoch: int | None = 0) -> ImuAttitude | Bad:
        """Decode one received frame; never raises on bad input (``epoch``: as
        :meth:`fsw.comm.rover_can.RoverCan.decode`)."""
        if is_extended or frame_id != self.frame_id:
            return Bad(frame_id, "unknown_id", f"id 0x{frame_id:03X} is not {MSG}")
        if len(data) != self.msg.length:
            return Bad(frame_id, "dlc", f"{MSG}: {len(data)} bytes, expected {self.msg.length}")
        refused = self.e2e.verify(bytes(data), epoch)
        if refused is not None:
            return Bad(frame_id, *refused)
        try:
            s = self.codec.decode(bytes(data))
        except Exception as exc:  # noqa: BLE001 - cantools errors vary by version; a bad frame is data
            return Bad(frame_id, "decode", f"{MSG}: {exc}")
        return ImuAttitude(float(s["Roll"]), float(s["Pitch"]), float(s["YawRate"]),
                           bool(s["SelfTestFail"]), bool(s["Moving"]), int(s[COUNTER]))
