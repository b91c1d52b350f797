"""The rover's CAN application layer, sans I/O: frames of ``config/rover.dbc`` <-> typed values.

Both ends use it: the flight motor driver (``fsw.drivers.can_motors``) and the emulated motor
controllers of the bench (``hil_sim.hw.motor_controllers``). Frame ids, layouts and scales come
from the DBC (read with cantools); this module adds only what a DBC cannot say:

* the axis table: twelve motor controllers, ``{DRIVE,STEER,SHOULDER}_{FL,FR,RL,RR}``, whose
  frames are ``<AXIS>_CMD`` (0x200 + node), ``<AXIS>_STATUS`` (0x180 + node) and
  ``<AXIS>_HEARTBEAT`` (0x700 + node), plus ``ESTOP`` (0x000) and ``FSW_HEARTBEAT`` (0x701);
* the end-to-end protection of every frame (:mod:`fsw.comm.e2e`, laid out by the DBC's
  ``Counter`` and ``Checksum`` signals): encoders take the sender's full alive counter and fill
  the checksum (CRC XOR the counter's epoch); :meth:`RoverCan.decode` refuses a wrong length,
  set reserved bits and a checksum that fails under ``epoch`` (0 by default; ``None`` leaves
  the checksum to the receiver's :class:`fsw.comm.e2e.SequenceChecker`, which knows the
  freshness of the data id and checks counter and checksum together).

Nothing here raises on bad input from the wire: :meth:`RoverCan.decode` returns a
:class:`Bad` with the reason, so callers count and event it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import cantools

from fsw.comm.can_codec import CompiledMessage, compile_messages
from fsw.comm.e2e import E2ELayout

WHEELS = ("FL", "FR", "RL", "RR")
KINDS = ("DRIVE", "STEER", "SHOULDER")
AXES = tuple(f"{k}_{w}" for k in KINDS for w in WHEELS)
NMT_STATES = {0: "BootUp", 4: "Stopped", 5: "Operational", 127: "PreOperational"}
STATE_BOOTUP, STATE_STOPPED, STATE_OPERATIONAL, STATE_PREOP = 0, 4, 5, 127
FAULT_BITS = ("FaultTimeout", "FaultLimit", "FaultOvercurrent", "FaultEStop", "FaultDriver")
POSITION_WRAP_RAD = 1048.576  # the 20-bit Position signal at 0.001 rad wraps with this period
DEFAULT_DBC = Path(__file__).resolve().parent.parent.parent / "config" / "rover.dbc"


def wrap_position(pos_rad: float) -> float:
    """A joint position folded into the Position signal's range (it wraps like an encoder)."""
    half = POSITION_WRAP_RAD / 2
    return (pos_rad + half) % POSITION_WRAP_RAD - half


class AxisCommand(NamedTuple):
    """A decoded ``<AXIS>_CMD``: ``setpoint`` is rad/s for DRIVE, rad for STEER and SHOULDER."""

    axis: str
    setpoint: float
    enable: bool
    clear_faults: bool
    counter: int


class AxisStatus(NamedTuple):
    """A decoded ``<AXIS>_STATUS``; ``faults`` is the set of fault-bit names that are set."""

    axis: str
    position_rad: float
    velocity_radps: float
    current_a: float
    enabled: bool
    faults: frozenset[str]
    counter: int


class Heartbeat(NamedTuple):
    node: str  # "FSW" or an axis name
    state: int
    counter: int


class EStop(NamedTuple):
    engage: bool
    counter: int


@dataclass(frozen=True)
class Bad:
    """A frame that could not be accepted, and why (``unknown_id``, ``dlc``, ``checksum``, ``reserved``...)."""

    frame_id: int
    reason: str
    detail: str = ""


Decoded = AxisCommand | AxisStatus | Heartbeat | EStop | Bad


class RoverCan:
    """Encoder/decoder for every frame of the rover DBC."""

    def __init__(self, dbc_path: str | Path = DEFAULT_DBC) -> None:
        try:
            db = cantools.database.load_file(str(dbc_path))
        except (OSError, cantools.database.UnsupportedDatabaseFormatError) as exc:
            reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc).splitlines()[0]
            raise ValueError(f"{dbc_path}: not a readable CAN database ({reason})") from None
        if not isinstance(db, cantools.database.can.Database):
            raise ValueError(f"{dbc_path}: not a CAN database")
        self.db = db
        self._fault_sets: dict[tuple[Any, ...], frozenset[str]] = {}  # fault signals -> their names set
        self._msg = {m.name: m for m in db.messages}
        self._codec: dict[str, CompiledMessage] = compile_messages(db)  # packed/unpacked without cantools per frame
        missing = [n for n in self._required() if n not in self._msg]
        if missing:
            raise ValueError(f"{dbc_path}: DBC lacks frames {', '.join(missing[:4])}")
        # frame id -> (kind, node, compiled message)
        self.route: dict[int, tuple[str, str, CompiledMessage]] = {}
        # frame id -> a STATUS's signals as one tuple: position, velocity, current, enabled, counter, faults...
        self._status_values = {self._codec[f"{a}_STATUS"].frame_id: self._codec[f"{a}_STATUS"].values(
            ("Position", "Velocity", "Current", "Enabled", "Counter", *FAULT_BITS)) for a in AXES}
        # frame id, a COMMAND's packer (set-point, Enable, ClearFaults, Counter) and its E2E seal
        self._command_packers = {}
        for a in AXES:
            m = self._codec[f"{a}_CMD"]
            sig = "VelocityCmd" if a.startswith("DRIVE") else "PositionCmd"
            self._command_packers[a] = (m.frame_id, m.packer((sig, "Enable", "ClearFaults", "Counter")))
        # frame id and a STATUS's packer (position, velocity, current, Enabled, Counter, faults...):
        # the bench's twelve controllers send one each a frame
        self._status_packers = {}
        for a in AXES:
            m = self._codec[f"{a}_STATUS"]
            self._status_packers[a] = (m.frame_id, m.packer(
                ("Position", "Velocity", "Current", "Enabled", "Counter", *FAULT_BITS)))
        for axis in AXES:
            for kind in ("CMD", "STATUS", "HEARTBEAT"):
                m = self._codec[f"{axis}_{kind}"]
                self.route[m.frame_id] = (kind, axis, m)
        self.route[self._codec["ESTOP"].frame_id] = ("ESTOP", "FSW", self._codec["ESTOP"])
        self.route[self._codec["FSW_HEARTBEAT"].frame_id] = ("HEARTBEAT", "FSW", self._codec["FSW_HEARTBEAT"])
        self.node_id = {axis: self._msg[f"{axis}_HEARTBEAT"].frame_id - 0x700 for axis in AXES}
        self.node_id["FSW"] = self._msg["FSW_HEARTBEAT"].frame_id - 0x700
        #: frame id -> E2E layout, for every frame of the DBC (ValueError if one is unprotected)
        try:
            self.e2e: dict[int, E2ELayout] = {m.frame_id: E2ELayout.from_message(m) for m in db.messages}
        except ValueError as exc:
            raise ValueError(f"{dbc_path}: {exc}") from None

    @staticmethod
    def _required() -> list[str]:
        names = ["ESTOP", "FSW_HEARTBEAT"]
        for axis in AXES:
            names += [f"{axis}_CMD", f"{axis}_STATUS", f"{axis}_HEARTBEAT"]
        return names

    def frame_id(self, name: str) -> int:
        return int(self._msg[name].frame_id)

    # -- encoding -----------------------------------------------------------------------------
    def _protected(self, name: str, signals: dict[str, Any], counter: int) -> tuple[int, bytes]:
        msg = self._codec[name]
        signals["Counter"] = signals["Checksum"] = 0
        data = msg.encode(signals)
        return msg.frame_id, self.e2e[msg.frame_id].protect(data, counter)

    def encode_command(
        self, axis: str, setpoint: float, enable: bool, clear_faults: bool, counter: int
    ) -> tuple[int, bytes]:
        lim = 32.767 if axis.startswith("DRIVE") else 3.2767
        value = float(setpoint) if math.isfinite(setpoint) else 0.0
        frame_id, pack = self._command_packers[axis]
        data = pack(max(-lim, min(lim, value)), int(enable), int(clear_faults), counter & 0xF)
        return frame_id, self.e2e[frame_id].seal(data, counter >> 4)

    def encode_status(
        self,
        axis: str,
        position_rad: float,
        velocity_radps: float,
        current_a: float,
        enabled: bool,
        faults: set[str] | frozenset[str],
        counter: int,
    ) -> tuple[int, bytes]:
        frame_id, pack = self._status_packers[axis]
        data = pack(wrap_position(position_rad), max(-32.768, min(32.767, velocity_radps)),
                    max(-12.8, min(12.7, current_a)), int(enabled), counter & 0xF,
                    *[int(b in faults) for b in FAULT_BITS])
        return frame_id, self.e2e[frame_id].seal(data, counter >> 4)

    def encode_heartbeat(self, node: str, state: int, counter: int) -> tuple[int, bytes]:
        return self._protected("FSW_HEARTBEAT" if node == "FSW" else f"{node}_HEARTBEAT", {"State": state}, counter)

    def encode_estop(self, engage: bool, counter: int) -> tuple[int, bytes]:
        return self._protected("ESTOP", {"Engage": int(engage)}, counter)

    # -- decoding -----------------------------------------------------------------------------
    def decode(self, frame_id: int, data: bytes, is_extended: bool = False, epoch: int | None = 0) -> Decoded:
        """Decode one received frame; never raises on bad input. ``epoch``: the freshness the
        checksum must hold under (``None``: checked by the receiver's sequence check)."""
        route = None if is_extended else self.route.get(frame_id)
        if route is None:
            return Bad(frame_id, "unknown_id", f"id 0x{frame_id:03X}{' (extended)' if is_extended else ''}")
        kind, node, msg = route
        data = bytes(data)
        refused = self.e2e[frame_id].verify(data, epoch)
        if refused is not None:
            return Bad(frame_id, *refused)
        try:
            if kind == "STATUS":
                v = self._status_values[frame_id](data)
            else:
                s = msg.decode(data)
        except Exception as exc:  # noqa: BLE001 - cantools errors vary by version; a bad frame is data
            return Bad(frame_id, "decode", f"{msg.name}: {exc}")
        if kind == "STATUS":
            bits = v[5:]
            faults = self._fault_sets.get(bits)
            if faults is None:  # one frozenset per fault pattern, built once (a status a frame per axis)
                faults = self._fault_sets[bits] = frozenset(b for b, on in zip(FAULT_BITS, bits, strict=True) if on)
            return AxisStatus(node, float(v[0]), float(v[1]), float(v[2]), bool(v[3]), faults, int(v[4]))
        if kind == "CMD":
            sp = s["VelocityCmd"] if "VelocityCmd" in s else s["PositionCmd"]
            return AxisCommand(node, float(sp), bool(s["Enable"]), bool(s["ClearFaults"]), int(s["Counter"]))
        if kind == "ESTOP":
            return EStop(bool(s["Engage"]), int(s["Counter"]))
        return Heartbeat(node, int(s["State"]), int(s["Counter"]))
