"""Executive telemetry and events as MAVLink common-dialect messages (docs/ground.md).

Pure builders and mappings, shared by the flight adapter and the ground tools:

* mission state -> HEARTBEAT ``base_mode`` (standard flags) / ``custom_mode`` (the state's
  index) / ``system_status``;
* F Prime event severity -> MAV_SEVERITY, events -> STATUSTEXT chunks;
* the world pose (z up, yaw CCW from +x; fsw/core/geometry.py) -> LOCAL_POSITION_NED and
  ATTITUDE (north = +x, east = -y, down = -z), the mast pan/tilt -> a gimbal quaternion;
* telemetry channels -> NAMED_VALUE_FLOAT / NAMED_VALUE_INT with a 10-character key
  ``"<id>:<local name>"`` (truncated) resolved by the ground through the dictionary, whose
  identity travels as ``NAMED_VALUE_INT dict_crc``.
"""

from __future__ import annotations

import json
import math
import zlib
from collections.abc import Iterable
from typing import Any

from fsw.comm.mavlink_dialect import mavlink
from fsw.core.geometry import wrap_angle
from fsw.framework.telemetry import Severity

#: The RECON-bot's mission sequencer's states (fsw/tasks/mission.py STATES; a test keeps them equal).
MISSION_STATES = ("IDLE", "INIT", "SELECT", "MOVE", "POINT", "ACQUIRE", "TRANSMIT", "DONE", "SAFE")
#: The Cliff-bot's mission states that the RECON-bot's do not have (fsw/tasks/cliffbot/checkpoint.py
#: STATES; its DONE and SAFE are the RECON-bot's). New states are appended: the modes keep their numbers.
CLIFFBOT_STATES = ("WAIT_MAP", "PLAN", "WAIT_FIX", "DRIVE", "DWELL", "SENSE")
#: custom_mode = index in this table, one table for every agent (docs/ground.md, "Modes");
#: 255 = a state not listed here.
MODES = MISSION_STATES + CLIFFBOT_STATES
UNKNOWN_MODE = 255
#: the project's vehicles by MAVLink system id (docs/ground.md): topic prefixes in recordings, names
#: in the ground tools and the MAVProxy module
VEHICLE_NAMES = {1: "recon", 2: "cliffbot"}
_IDLE_STATES = {"IDLE", "DONE"}
_MOVING_STATES = {"INIT", "MOVE", "POINT", "DRIVE"}  # wheels, winches or mast may move: SAFETY_ARMED

MAV_SEVERITY_OF = {
    Severity.FATAL: mavlink.MAV_SEVERITY_EMERGENCY,
    Severity.WARNING_HI: mavlink.MAV_SEVERITY_ERROR,
    Severity.WARNING_LO: mavlink.MAV_SEVERITY_WARNING,
    Severity.COMMAND: mavlink.MAV_SEVERITY_NOTICE,
    Severity.ACTIVITY_HI: mavlink.MAV_SEVERITY_INFO,
    Severity.ACTIVITY_LO: mavlink.MAV_SEVERITY_INFO,
    Severity.DIAGNOSTIC: mavlink.MAV_SEVERITY_DEBUG,
}
STATUSTEXT_CHUNK = 50
STATUSTEXT_MAX_CHUNKS = 4
DICT_CRC_KEY = "dict_crc"
NAMED_VALUE_KEY_LEN = 10
_INT32 = (-(2**31), 2**31 - 1)


def mode_name(custom_mode: int) -> str:
    return MODES[custom_mode] if 0 <= custom_mode < len(MODES) else f"MODE_{custom_mode}"


def mode_fields(state: Any, fatal: bool, simulated: bool) -> tuple[int, int, int]:
    """``(base_mode, custom_mode, system_status)`` for the mission state channel's value.

    ``state`` is the channel value: a state name (str), its index (int) or None (no
    sequencer yet: IDLE). ``fatal`` (health reports a hung task) forces MAV_STATE_EMERGENCY.
    """
    if state is None:
        name = "IDLE"
    elif isinstance(state, str):
        name = state.upper()
    else:
        try:
            idx = int(state)
        except (TypeError, ValueError, OverflowError):
            idx = UNKNOWN_MODE
        name = mode_name(idx)
    custom = MODES.index(name) if name in MODES else UNKNOWN_MODE
    # standard mode flags only (no MAV_MODE_FLAG_CUSTOM_MODE_ENABLED): a stock ground station then
    # names the mode from the flags (QGroundControl: "Auto"; MAVProxy: the flags in hex) instead
    # of reading custom_mode through another autopilot's table (MAVProxy showed ArduRover's names).
    # custom_mode still carries the state's index for the project's tools (docs/ground.md, "Modes").
    base = 0
    if simulated:
        base |= mavlink.MAV_MODE_FLAG_HIL_ENABLED
    if name not in _IDLE_STATES and name != "SAFE":
        base |= mavlink.MAV_MODE_FLAG_AUTO_ENABLED  # the mission sequencer is in charge
    if name in _MOVING_STATES:
        base |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    if fatal:
        status = mavlink.MAV_STATE_EMERGENCY
    elif name == "SAFE":
        status = mavlink.MAV_STATE_CRITICAL
    elif name in _IDLE_STATES:
        status = mavlink.MAV_STATE_STANDBY
    else:
        status = mavlink.MAV_STATE_ACTIVE
    return base, custom, status


def heartbeat(state: Any, fatal: bool, simulated: bool) -> mavlink.MAVLink_heartbeat_message:
    base, custom, status = mode_fields(state, fatal, simulated)
    return mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_GROUND_ROVER, mavlink.MAV_AUTOPILOT_GENERIC,
                                             base, custom, status, 3)


def statustext(severity: Severity, text: str, chunk_id: int) -> list[mavlink.MAVLink_statustext_message]:
    """One STATUSTEXT, or up to 4 chunks sharing ``chunk_id`` (MAVLink 2 long messages).

    A text of exactly 50 * k bytes gets an empty last chunk, so a chunk shorter than 50
    bytes always ends the text for the receiver.
    """
    raw = text.encode("utf-8", "replace")
    limit = STATUSTEXT_CHUNK * STATUSTEXT_MAX_CHUNKS - 1  # the last chunk stays short: it ends the text
    if len(raw) > limit:
        raw = raw[:limit - 3] + b"..."
    sev = MAV_SEVERITY_OF[severity]
    if len(raw) <= STATUSTEXT_CHUNK:
        return [mavlink.MAVLink_statustext_message(sev, raw, 0, 0)]
    chunks = [raw[i:i + STATUSTEXT_CHUNK] for i in range(0, len(raw) + 1, STATUSTEXT_CHUNK)]
    return [mavlink.MAVLink_statustext_message(sev, c, chunk_id, k) for k, c in enumerate(chunks)]


def channel_key(channel_id: int, full_name: str) -> str:
    """The NAMED_VALUE name of a channel: its dictionary name when that fits the 10 characters
    (a stock tool shows it as it is, e.g. ``exec.slips``), else ``"<id>:<local name>"`` truncated,
    which the ground resolves through the dictionary."""
    if len(full_name) <= NAMED_VALUE_KEY_LEN and ":" not in full_name:
        return full_name
    local = full_name.split(".", 1)[-1]
    return f"{channel_id}:{local}"[:NAMED_VALUE_KEY_LEN]


def parse_channel_key(key: str) -> int | None:
    """The channel id of a NAMED_VALUE key, or None for other names (e.g. ``dict_crc``)."""
    head, sep, _ = key.partition(":")
    return int(head) if sep and head.isdigit() else None


def dictionary_crc(channels: Iterable[tuple[int, str]]) -> int:
    """CRC-32 (as int32) of the channel ids and names: ground and flight must agree."""
    blob = json.dumps(sorted((int(i), str(n)) for i, n in channels)).encode()
    crc = zlib.crc32(blob)
    return crc - 2**32 if crc >= 2**31 else crc


def named_value(time_boot_ms: int, key: str, value: Any) -> mavlink.MAVLink_message | None:
    """NAMED_VALUE_INT for integers in int32, NAMED_VALUE_FLOAT for other numbers, else None."""
    name = key.encode()[:NAMED_VALUE_KEY_LEN]
    if isinstance(value, bool) or (hasattr(value, "dtype") and value.dtype.kind in "biu"):
        value = int(value)
    if isinstance(value, int):
        if _INT32[0] <= value <= _INT32[1]:
            return mavlink.MAVLink_named_value_int_message(time_boot_ms, name, value)
        return mavlink.MAVLink_named_value_float_message(time_boot_ms, name, float(value))
    try:
        return mavlink.MAVLink_named_value_float_message(time_boot_ms, name, float(value))
    except (TypeError, ValueError, OverflowError):
        return None  # strings and other non-numbers do not travel as NAMED_VALUE


def euler_to_quaternion(roll: float, pitch: float, yaw: float) -> list[float]:
    """``[w, x, y, z]`` for intrinsic Z-Y-X (yaw, pitch, roll) angles, radians."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return [cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy]



def local_position_ned(time_boot_ms: int, xyz: tuple[float, float, float],
                       vel: tuple[float, float, float]) -> mavlink.MAVLink_local_position_ned_message:
    """World (x, y, z up) -> NED (north = x, east = -y, down = -z)."""
    (x, y, z), (vx, vy, vz) = xyz, vel
    return mavlink.MAVLink_local_position_ned_message(time_boot_ms, x, -y, -z, vx, -vy, -vz)


def attitude(time_boot_ms: int, rpy: tuple[float, float, float],
             rates: tuple[float, float, float]) -> mavlink.MAVLink_attitude_message:
    """Body FLU in the z-up world -> FRD in NED: roll kept, pitch and yaw negated."""
    (r, p, y), (rr, pr, yr) = rpy, rates
    return mavlink.MAVLink_attitude_message(time_boot_ms, r, -p, wrap_angle(-y), rr, -pr, -yr)


def mast_attitude(time_boot_ms: int, pan_rad: float, tilt_rad: float) -> mavlink.MAVLink_message:
    """The mast head as a gimbal relative to the rover (yaw = -pan in FRD, pitch = tilt up)."""
    q = euler_to_quaternion(0.0, tilt_rad, wrap_angle(-pan_rad))
    nan = float("nan")
    return mavlink.MAVLink_gimbal_device_attitude_status_message(
        0, 0, time_boot_ms, mavlink.GIMBAL_DEVICE_FLAGS_YAW_IN_VEHICLE_FRAME, q, nan, nan, nan, 0,
        nan, nan, 1)


def mast_pan_tilt(msg: Any) -> tuple[float, float]:
    """Inverse of :func:`mast_attitude` for the ground: ``(pan_rad, tilt_rad)``."""
    w, x, y, z = msg.q
    pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return -yaw, pitch
