"""What the ground knows about the rover, built from MAVLink messages (live link or .tlog).

One :meth:`GroundState.feed` per message: mode from HEARTBEAT, link statistics (bytes,
sequence gaps = lost frames), SYS_STATUS, pose, mast, channel values named through the
dictionary, events (long STATUSTEXT chunks reassembled) and map previews.

Several vehicles share a link (the RECON-bot is MAVLink system 1, the Cliff-bot system 2):
:class:`Fleet` keeps one :class:`GroundState` per system id, made at its first HEARTBEAT, and
names them by :data:`VEHICLE_NAMES` (``sys<N>`` for others).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from typing import Any

from fsw.comm.mavlink_dialect import mavlink
from fsw.comm.mavlink_image import ImageReceiver
from fsw.comm.mavlink_telemetry import DICT_CRC_KEY, VEHICLE_NAMES, mast_pan_tilt, mode_name
from ground.dictionary import GroundDictionary

SEVERITY_NAMES = {e: v.name.removeprefix("MAV_SEVERITY_") for e, v in mavlink.enums["MAV_SEVERITY"].items()}
STATE_NAMES = {e: v.name.removeprefix("MAV_STATE_") for e, v in mavlink.enums["MAV_STATE"].items()}


def vehicle_name(system_id: int) -> str:
    return VEHICLE_NAMES.get(system_id, f"sys{system_id}")


@dataclass
class EventLine:
    time_s: float
    severity: int
    text: str


@dataclass
class GroundState:
    dictionary: GroundDictionary
    system_id: int | None = None  # the rover's, from its first HEARTBEAT
    heartbeat_s: float | None = None
    heartbeat: Any = None
    sys_status: Any = None
    position_ned: tuple[float, float, float] | None = None
    yaw_ned: float | None = None
    mast: tuple[float, float] | None = None
    remote_crc: int | None = None
    channels: dict[str, tuple[float, float]] = field(default_factory=dict)  # name -> (value, time)
    events: deque[EventLine] = field(default_factory=lambda: deque(maxlen=200))
    images: ImageReceiver = field(default_factory=ImageReceiver)
    frames: int = 0
    rx_bytes: int = 0
    lost: int = 0
    _seq: int | None = None
    _chunks: dict[int, list[bytes]] = field(default_factory=dict)
    _rate: deque[tuple[float, int]] = field(default_factory=lambda: deque(maxlen=4096))

    def feed(self, msg: Any, t: float) -> None:
        kind = msg.get_type()
        if kind == "BAD_DATA":
            return
        hdr = msg.get_header()
        if kind == "HEARTBEAT" and msg.type == mavlink.MAV_TYPE_GCS:
            return  # another ground station (or our own echo)
        if self.system_id is None and kind == "HEARTBEAT":
            self.system_id = hdr.srcSystem
        if self.system_id is not None and hdr.srcSystem != self.system_id:
            return
        n = len(msg.get_msgbuf())
        self.frames += 1
        self.rx_bytes += n
        self._rate.append((t, n))
        if self._seq is not None:
            self.lost += (hdr.seq - self._seq - 1) % 256
        self._seq = hdr.seq
        handler = getattr(self, f"_on_{kind.lower()}", None)
        if handler is not None:
            handler(msg, t)
        else:
            self.images.feed(msg, t)

    # -- per message ----------------------------------------------------------------------------
    def _on_heartbeat(self, msg: Any, t: float) -> None:
        self.heartbeat, self.heartbeat_s = msg, t

    def _on_sys_status(self, msg: Any, t: float) -> None:
        self.sys_status = msg

    def _on_local_position_ned(self, msg: Any, t: float) -> None:
        self.position_ned = (msg.x, msg.y, msg.z)

    def _on_attitude(self, msg: Any, t: float) -> None:
        self.yaw_ned = msg.yaw

    def _on_gimbal_device_attitude_status(self, msg: Any, t: float) -> None:
        self.mast = mast_pan_tilt(msg)

    def _on_named_value_int(self, msg: Any, t: float) -> None:
        key = _text(msg.name)
        if key == DICT_CRC_KEY:
            self.remote_crc = int(msg.value)
            return
        self.channels[self.dictionary.channel_name(key, self.remote_crc)] = (msg.value, t)

    def _on_named_value_float(self, msg: Any, t: float) -> None:
        self.channels[self.dictionary.channel_name(_text(msg.name), self.remote_crc)] = (msg.value, t)

    def _on_statustext(self, msg: Any, t: float) -> None:
        raw = msg.text if isinstance(msg.text, bytes) else str(msg.text).encode()
        cid = getattr(msg, "id", 0)
        if not cid:
            self.events.append(EventLine(t, msg.severity, raw.decode("utf-8", "replace")))
            return
        parts = self._chunks.setdefault(cid, [])
        parts.append(raw)
        if len(raw) < 50 or len(parts) >= 8:
            text = b"".join(self._chunks.pop(cid)).decode("utf-8", "replace")
            self.events.append(EventLine(t, msg.severity, text))

    # -- derived --------------------------------------------------------------------------------
    @property
    def dictionary_ok(self) -> bool | None:
        return None if self.remote_crc is None else self.remote_crc == self.dictionary.crc

    def mode(self) -> str:
        return "-" if self.heartbeat is None else mode_name(self.heartbeat.custom_mode)

    def status(self) -> str:
        return "-" if self.heartbeat is None else STATE_NAMES.get(self.heartbeat.system_status, "?")

    def rate_bps(self, now: float, window_s: float = 5.0) -> float:
        recent = [n for t, n in self._rate if now - t <= window_s]
        return 8.0 * sum(recent) / window_s

    def loss_pct(self) -> float:
        total = self.frames + self.lost
        return 100.0 * self.lost / total if total else math.nan


@dataclass
class Fleet:
    """One :class:`GroundState` per vehicle heard (MAVLink system id), in the order first heard."""

    dictionary: GroundDictionary
    vehicles: dict[int, GroundState] = field(default_factory=dict)

    def feed(self, msg: Any, t: float) -> GroundState | None:
        """Route ``msg`` to its vehicle's state (None: not a vehicle's, or before its first HEARTBEAT)."""
        kind = msg.get_type()
        if kind == "BAD_DATA" or (kind == "HEARTBEAT" and msg.type == mavlink.MAV_TYPE_GCS):
            return None
        sid = msg.get_srcSystem()
        st = self.vehicles.get(sid)
        if st is None:
            if kind != "HEARTBEAT":
                return None
            st = self.vehicles[sid] = GroundState(self.dictionary)
        st.feed(msg, t)
        return st

    def pick(self, system_id: int | None) -> GroundState | None:
        """The state of ``system_id``, or of the lowest system id heard when None."""
        if system_id is not None:
            return self.vehicles.get(system_id)
        return self.vehicles[min(self.vehicles)] if self.vehicles else None


def _text(v: Any) -> str:
    return v.decode("utf-8", "replace") if isinstance(v, bytes) else str(v)
