"""The team's CAN application layer, sans I/O: frames of ``config/team.dbc`` <-> typed values.

The two Anchorbots' tether winches (``WINCH_A``, ``WINCH_B``: a rate command; paid-out
length, tension and fault bits back), the Cliff-bot's wheels (two wheel-rate commands;
wheel angles back) and its attitude sensor. Both ends use it: the Cliff-bot's flight code
(:mod:`fsw.drivers.cliffbot_devices`) and the bench's emulated nodes
(:mod:`hil_sim.hw.winch`). Every frame is end-to-end protected exactly like the rover's
(:mod:`fsw.comm.e2e`, laid out from the DBC); :meth:`TeamCan.decode` never raises on bad
input: it returns a :class:`~fsw.comm.rover_can.Bad` with the reason.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import cantools

from fsw.comm.can_codec import CompiledMessage, compile_messages
from fsw.comm.e2e import E2ELayout
from fsw.comm.rover_can import Bad

TEAM_DBC = Path(__file__).resolve().parents[3] / "config" / "team.dbc"
WINCHES = ("WINCH_A", "WINCH_B")
WINCH_FAULTS = ("FaultTimeout", "FaultStall", "FaultSlip", "FaultOverTension", "FaultSpool")


class WinchCommand(NamedTuple):
    winch: str
    rate_mps: float  # paying out is positive
    enable: bool
    clear_faults: bool
    counter: int


class WinchStatus(NamedTuple):
    winch: str
    paid_out_m: float
    tension_n: float
    enabled: bool
    faults: frozenset[str]
    counter: int


class WheelCommand(NamedTuple):
    left_radps: float
    right_radps: float
    enable: bool
    counter: int


class WheelStatus(NamedTuple):
    left_rad: float
    right_rad: float
    enabled: bool
    counter: int


class Attitude(NamedTuple):
    roll_deg: float
    pitch_deg: float
    yaw_deg: float
    counter: int


TeamFrame = WinchCommand | WinchStatus | WheelCommand | WheelStatus | Attitude | Bad


def _finite(v: float, lim: float) -> float:
    return max(-lim, min(lim, float(v))) if math.isfinite(v) else 0.0


@dataclass
class TeamCan:
    """Encoder/decoder for every frame of the team DBC."""

    dbc_path: Path = TEAM_DBC

    def __post_init__(self) -> None:
        try:
            db = cantools.database.load_file(str(self.dbc_path))
        except (OSError, cantools.database.UnsupportedDatabaseFormatError) as exc:
            raise ValueError(f"{self.dbc_path}: not a readable CAN database ({str(exc).splitlines()[0]})") from None
        if not isinstance(db, cantools.database.can.Database):
            raise ValueError(f"{self.dbc_path}: not a CAN database")
        self._codec: dict[str, CompiledMessage] = compile_messages(db)
        need = [f"{w}_{k}" for w in WINCHES for k in ("CMD", "STATUS")] + [
            "CB_WHEELS_CMD", "CB_WHEELS_STATUS", "CB_IMU_ATTITUDE"]
        missing = [n for n in need if n not in self._codec]
        if missing:
            raise ValueError(f"{self.dbc_path}: DBC lacks frames {', '.join(missing)}")
        self.e2e = {m.frame_id: E2ELayout.from_message(m) for m in db.messages}
        self.names = {m.frame_id: m.name for m in db.messages}

    def frame_id(self, name: str) -> int:
        return int(self._codec[name].frame_id)

    def _encode(self, name: str, signals: dict[str, float | int], counter: int) -> tuple[int, bytes]:
        msg = self._codec[name]
        signals["Counter"] = signals["Checksum"] = 0
        return msg.frame_id, self.e2e[msg.frame_id].protect(msg.encode(signals), counter)

    def winch_command(self, winch: str, rate_mps: float, enable: bool, clear: bool, counter: int
                      ) -> tuple[int, bytes]:
        return self._encode(f"{winch}_CMD", {"RateCmd": _finite(rate_mps, 3.2767), "Enable": int(enable),
                                             "ClearFaults": int(clear)}, counter)

    def winch_status(self, winch: str, paid_out_m: float, tension_n: float, enabled: bool,
                     faults: set[str] | frozenset[str], counter: int) -> tuple[int, bytes]:
        sig: dict[str, float | int] = {"PaidOut": min(104.8575, max(0.0, paid_out_m)),
                                       "Tension": min(6553.5, max(0.0, tension_n)), "Enabled": int(enabled)}
        sig.update({b: int(b in faults) for b in WINCH_FAULTS})
        return self._encode(f"{winch}_STATUS", sig, counter)

    def wheel_command(self, left: float, right: float, enable: bool, counter: int) -> tuple[int, bytes]:
        return self._encode("CB_WHEELS_CMD", {"LeftCmd": _finite(left, 32.767), "RightCmd": _finite(right, 32.767),
                                              "Enable": int(enable)}, counter)

    def wheel_status(self, left_rad: float, right_rad: float, enabled: bool, counter: int) -> tuple[int, bytes]:
        wrap = 1048.576

        def fold(a: float) -> float:
            return (a + wrap / 2) % wrap - wrap / 2

        return self._encode("CB_WHEELS_STATUS", {"LeftPos": fold(left_rad), "RightPos": fold(right_rad),
                                                 "Enabled": int(enabled)}, counter)

    def attitude(self, roll_deg: float, pitch_deg: float, yaw_deg: float, counter: int) -> tuple[int, bytes]:
        return self._encode("CB_IMU_ATTITUDE", {"Roll": _finite(roll_deg, 180.0), "Pitch": _finite(pitch_deg, 90.0),
                                                "Yaw": _finite(yaw_deg, 180.0)}, counter)

    def decode(self, frame_id: int, data: bytes, epoch: int | None = 0) -> TeamFrame:
        """One received frame, typed; a :class:`Bad` (never an exception) when it is not acceptable.
        ``epoch``: the freshness the checksum must hold under (``None``: the receiver's
        :meth:`~fsw.comm.e2e.SequenceChecker.check_frame` checks it)."""
        name = self.names.get(frame_id)
        if name is None:
            return Bad(frame_id, "unknown_id", f"id 0x{frame_id:03X}")
        data = bytes(data)
        refused = self.e2e[frame_id].verify(data, epoch)
        if refused is not None:
            return Bad(frame_id, *refused)
        try:
            s = self._codec[name].decode(data)
        except Exception as exc:  # noqa: BLE001 - a bad frame is data, whatever the codec raised
            return Bad(frame_id, "decode", f"{name}: {exc}")
        c = int(s["Counter"])
        if name.endswith("_CMD") and name.startswith("WINCH"):
            return WinchCommand(name[:-4], float(s["RateCmd"]), bool(s["Enable"]), bool(s["ClearFaults"]), c)
        if name.startswith("WINCH"):
            faults = frozenset(b for b in WINCH_FAULTS if s[b])
            return WinchStatus(name[:-7], float(s["PaidOut"]), float(s["Tension"]), bool(s["Enabled"]), faults, c)
        if name == "CB_WHEELS_CMD":
            return WheelCommand(float(s["LeftCmd"]), float(s["RightCmd"]), bool(s["Enable"]), c)
        if name == "CB_WHEELS_STATUS":
            return WheelStatus(float(s["LeftPos"]), float(s["RightPos"]), bool(s["Enabled"]), c)
        return Attitude(float(s["Roll"]), float(s["Pitch"]), float(s["Yaw"]), c)
