"""SAFER's modes for a stock ground station: the MAVProxy module's logic, without MAVProxy.

A SAFER vehicle's HEARTBEAT (MAV_TYPE_GROUND_ROVER, MAV_AUTOPILOT_GENERIC, standard mode flags)
carries its mission state's index in ``custom_mode`` (``fsw.comm.mavlink_telemetry.MODES``, one
table for the RECON-bot, system 1, and the Cliff-bot, system 2). pymavlink names such a mode
only by its flags (``Mode(0x000000a4)``); :class:`FleetModes` names it, keeps each vehicle's
mode, status and last event, and turns a mode request (``SAFE``, ``START``, ``RESUME``,
``RECOVER``) into the vehicle's own dictionary command, sent as the project's signed command
(COMMAND_LONG ``MAV_CMD_USER_1``, ``param1`` = the opcode; docs/ground.md, "Commands"). The
opcodes come from the vehicle's dictionary (``safer-fsw --config FILE dictionary > FILE.json``).

Only pymavlink and ``fsw.comm`` are imported, so MAVProxy's own environment can load it.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fsw.comm.mavlink_commands import Reason, result_name
from fsw.comm.mavlink_dialect import mavlink
from fsw.comm.mavlink_telemetry import VEHICLE_NAMES, mode_name

#: a requested mode -> the dictionary commands that reach it, the first the vehicle has is sent
REQUESTS: dict[str, tuple[str, ...]] = {
    "SAFE": ("mission.ABORT",),
    "START": ("mission.START",),
    "RESUME": ("mission.RESUME", "mission.RECOVER"),
    "RECOVER": ("mission.RECOVER", "mission.RESUME"),
}
STATE_NAMES = {e: v.name.removeprefix("MAV_STATE_") for e, v in mavlink.enums["MAV_STATE"].items()}


class RequestError(ValueError):
    """A mode request that cannot be sent (the reason in one line)."""


@dataclass
class Vehicle:
    system: int
    mode: str = "-"
    status: str = "-"
    armed: bool = False
    heard_s: float = 0.0
    changes: int = 0
    last_event: str = ""
    commands: dict[str, int] = field(default_factory=dict)  # dictionary name -> opcode

    @property
    def name(self) -> str:
        return VEHICLE_NAMES.get(self.system, f"sys{self.system}")


class FleetModes:
    """The vehicles of ``systems`` as seen in their HEARTBEAT, STATUSTEXT and COMMAND_ACK."""

    def __init__(self, systems: tuple[int, ...] = tuple(VEHICLE_NAMES)) -> None:
        self.systems = systems
        self.vehicles: dict[int, Vehicle] = {}
        self.pending: dict[tuple[int, int], str] = {}  # (system, opcode) -> command name, until its ACK

    # -- naming ---------------------------------------------------------------------------------
    def is_ours(self, msg: Any) -> bool:
        """A SAFER vehicle's HEARTBEAT (type, autopilot, no custom-mode flag, a system of ours)."""
        return (msg.get_type() == "HEARTBEAT" and msg.get_srcSystem() in self.systems
                and msg.type == mavlink.MAV_TYPE_GROUND_ROVER and msg.autopilot == mavlink.MAV_AUTOPILOT_GENERIC
                and not msg.base_mode & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED)

    def mode_string(self, msg: Any) -> str | None:
        """The mode's name for one of our HEARTBEATs, None for any other message."""
        return mode_name(int(msg.custom_mode)) if self.is_ours(msg) else None

    # -- the link -------------------------------------------------------------------------------
    def feed(self, msg: Any, now: float) -> list[str]:
        """Take one received message; the lines worth printing (a mode change, an answer)."""
        kind, sysid = msg.get_type(), msg.get_srcSystem()
        if kind == "HEARTBEAT":
            name = self.mode_string(msg)
            if name is None:
                return []
            v = self.vehicles.setdefault(sysid, Vehicle(sysid))
            v.heard_s, v.armed = now, bool(msg.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
            v.status = STATE_NAMES.get(msg.system_status, "?")
            if name == v.mode:
                return []
            old, v.mode = v.mode, name
            v.changes += old != "-"
            return [f"{v.name} (system {sysid}): mode {name}" if old == "-" else
                    f"{v.name} (system {sysid}): mode {old} -> {name}"]
        if sysid not in self.systems:
            return []
        if kind == "STATUSTEXT" and sysid in self.vehicles and not getattr(msg, "chunk_seq", 0):
            self.vehicles[sysid].last_event = _text(msg.text)  # (the first chunk of a long one)
        elif kind == "COMMAND_ACK" and msg.command == mavlink.MAV_CMD_USER_1:
            name = self.pending.pop((sysid, int(msg.result_param2)), None)
            if name is not None:
                return [f"{VEHICLE_NAMES.get(sysid, sysid)}: {name} -> {ack_text(msg)}"]
        return []

    def status_lines(self, now: float) -> list[str]:
        if not self.vehicles:
            return [f"no SAFER vehicle heard yet (systems {', '.join(map(str, self.systems))})"]
        return [f"{v.name:<9} system {v.system}  mode {v.mode:<9} {v.status:<9} "
                f"{'ARMED' if v.armed else 'disarmed':<8} heard {now - v.heard_s:5.1f} s ago  "
                f"{v.changes} mode change(s)"
                + (f"  last event: {v.last_event}" if v.last_event else "")
                for v in sorted(self.vehicles.values(), key=lambda v: v.system)]

    def prompt(self) -> str:
        """Every vehicle's mode, e.g. ``recon:MOVE cliffbot:WAIT_MAP``."""
        return " ".join(f"{v.name}:{v.mode}" for v in sorted(self.vehicles.values(), key=lambda v: v.system))

    # -- requests -------------------------------------------------------------------------------
    def load_dictionary(self, system: int, path: str | Path) -> int:
        """Read a vehicle's dictionary (``safer-fsw dictionary`` JSON); the number of commands."""
        try:
            data = json.loads(Path(path).read_text())
            commands = {str(c["name"]): int(c["opcode"]) for c in data["commands"]}
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise RequestError(f"{path}: not a dictionary from `safer-fsw dictionary` ({exc})") from None
        self.vehicles.setdefault(system, Vehicle(system)).commands = commands
        return len(commands)

    def request(self, mode: str, system: int) -> tuple[str, int, mavlink.MAVLink_command_long_message]:
        """The command that asks ``system`` for ``mode``: (name, opcode, COMMAND_LONG to send)."""
        wanted = REQUESTS.get(mode.upper())
        if wanted is None:
            raise RequestError(f"no mode request {mode!r}: one of {', '.join(REQUESTS)}")
        v = self.vehicles.get(system)
        if v is None or not v.commands:
            raise RequestError(f"no dictionary for system {system}: `safer dictionary {system} FILE.json` "
                               "(from `safer-fsw --config FILE dictionary`)")
        for name in wanted:
            if name in v.commands:
                op = v.commands[name]
                self.pending[(system, op)] = name
                msg = mavlink.MAVLink_command_long_message(system, 1, mavlink.MAV_CMD_USER_1, 0,
                                                           float(op), 0, 0, 0, 0, 0, 0)
                return name, op, msg
        raise RequestError(f"{v.name} (system {system}) has no command for {mode.upper()} "
                           f"(looked for {', '.join(wanted)})")


def ack_text(msg: Any) -> str:
    """``ACCEPTED``, ``DENIED (UNSIGNED)``, ... for the COMMAND_ACK of a dictionary command."""
    text = result_name(int(msg.result))
    if msg.result != mavlink.MAV_RESULT_ACCEPTED and msg.progress:
        try:
            text += f" ({Reason(int(msg.progress)).name})"
        except ValueError:
            text += f" (reason {msg.progress})"
    if msg.result == mavlink.MAV_RESULT_DENIED and msg.progress == Reason.UNSIGNED:
        text += ": set the key first (`signing key PASSPHRASE`)"
    return text


def _text(raw: Any) -> str:
    return (raw.decode("utf-8", "replace") if isinstance(raw, bytes) else str(raw)).rstrip("\x00")
