"""The executive's command dictionary carried in MAVLink COMMAND_LONG, and its COMMAND_ACK.

Mapping (docs/ground.md, "Commands"): ``command = MAV_CMD_USER_1`` (31010), ``param1`` =
the dictionary opcode (``safer-fsw dictionary``), ``param2..param7`` = the arguments in
declared order:

* ``int`` / ``float``: the value (COMMAND_LONG params are float32: integers are exact up to
  2**24, floats carry float32 precision);
* ``bool``: 1 or 0;
* ``str`` with ``choices``: the index into ``choices``;
* one ``str`` without choices per command: packed UTF-8 into the params left after the other
  arguments, 3 bytes per param as an integer ``b0 << 16 | b1 << 8 | b2``, zero padded.

COMMAND_ACK answers every COMMAND_LONG addressed to us: ``result`` = ACCEPTED (OK), DENIED
(refused before running: not authenticated, bad arguments, unknown opcode), FAILED
(``EXECUTION_ERROR``) or UNSUPPORTED (another ``command`` id); ``progress`` (the spec's
``result_param1``) = a :class:`Reason` code for DENIED; ``result_param2`` = the opcode.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Mapping, Sequence
from typing import Any

from fsw.comm.mavlink_dialect import mavlink
from fsw.framework.commands import Arg, CommandDef, CommandStatus

N_ARG_PARAMS = 6  # param2..param7
BYTES_PER_PARAM = 3
_FLOAT32_EXACT_INT = 2**24


class Reason(enum.IntEnum):
    """Why a command was DENIED (COMMAND_ACK.progress)."""

    NONE = 0
    UNSIGNED = 1
    BAD_SIGNATURE = 2
    REPLAY = 3
    STALE = 4
    NO_KEY = 5
    FUTURE = 6
    UNRECORDED = 7  # signed and fresh, but the replay window could not be saved: not executed
    BUSY = 8  # more than commands_per_frame in one activation (TEMPORARILY_REJECTED)
    BAD_ARGUMENTS = 10
    UNKNOWN_OPCODE = 11
    VALIDATION = 12


RESULT_OF_STATUS = {
    CommandStatus.OK: mavlink.MAV_RESULT_ACCEPTED,
    CommandStatus.VALIDATION_ERROR: mavlink.MAV_RESULT_DENIED,
    CommandStatus.EXECUTION_ERROR: mavlink.MAV_RESULT_FAILED,
}


def result_name(result: int) -> str:
    entry = mavlink.enums["MAV_RESULT"].get(result)
    return entry.name.removeprefix("MAV_RESULT_") if entry is not None else f"RESULT_{result}"


def _free_string(cdef: CommandDef) -> Arg | None:
    free = [a for a in cdef.args if a.kind is str and not a.choices]
    if len(free) > 1:
        raise ValueError(f"{cdef.name}: more than one free string argument cannot be sent in COMMAND_LONG")
    return free[0] if free else None


def string_capacity(cdef: CommandDef) -> int:
    """Bytes available to the free string argument of ``cdef`` (0 if it has none)."""
    return (N_ARG_PARAMS - (len(cdef.args) - 1)) * BYTES_PER_PARAM if _free_string(cdef) else 0


def encode_args(cdef: CommandDef, args: Mapping[str, Any]) -> list[float]:
    """``param2..param7`` for a command; raises ``ValueError`` naming the argument."""
    free = _free_string(cdef)
    fixed = [a for a in cdef.args if a is not free]
    if len(fixed) + (1 if free else 0) > N_ARG_PARAMS:
        raise ValueError(f"{cdef.name}: {len(cdef.args)} arguments do not fit the 6 free COMMAND_LONG params")
    params = [0.0] * N_ARG_PARAMS
    for i, a in enumerate(fixed):
        if a.name not in args:
            raise ValueError(f"missing argument {a.name!r}")
        params[i] = _encode_one(a, args[a.name])
    if free is not None:
        if free.name not in args:
            raise ValueError(f"missing argument {free.name!r}")
        raw = str(args[free.name]).encode("utf-8")
        cap = (N_ARG_PARAMS - len(fixed)) * BYTES_PER_PARAM
        if len(raw) > cap or b"\x00" in raw:
            raise ValueError(f"{free.name}: at most {cap} UTF-8 bytes without NUL fit, got {len(raw)}")
        raw = raw.ljust(cap, b"\x00")
        for j in range(N_ARG_PARAMS - len(fixed)):
            params[len(fixed) + j] = float(int.from_bytes(raw[3 * j:3 * j + 3], "big"))
    return params


def _encode_one(a: Arg, value: Any) -> float:
    if a.kind is bool:
        return 1.0 if bool(value) else 0.0
    if a.kind is str:
        assert a.choices is not None
        if value not in a.choices:
            raise ValueError(f"{a.name}: must be one of {list(a.choices)}, got {value!r}")
        return float(a.choices.index(value))
    x = float(value)
    if a.kind is int and abs(x) >= _FLOAT32_EXACT_INT:
        raise ValueError(f"{a.name}: {value} is too large to travel exactly in a float32 param")
    return x


def decode_args(cdef: CommandDef, params: Sequence[float]) -> dict[str, Any]:
    """Arguments from ``param2..param7``; raises ``ValueError`` on what cannot be decoded.

    Range and type checks beyond the wire format are left to the command dispatcher.
    """
    free = _free_string(cdef)
    fixed = [a for a in cdef.args if a is not free]
    if len(fixed) + (1 if free else 0) > N_ARG_PARAMS:
        raise ValueError(f"{cdef.name} cannot be carried in COMMAND_LONG")
    out: dict[str, Any] = {}
    for a, p in zip(fixed, params, strict=False):
        out[a.name] = _decode_one(a, float(p))
    if free is not None:
        raw = bytearray()
        for p in params[len(fixed):N_ARG_PARAMS]:
            p = float(p)
            if not (math.isfinite(p) and p.is_integer() and 0 <= p < _FLOAT32_EXACT_INT):
                raise ValueError(f"{free.name}: param {p!r} is not a packed string chunk")
            raw += int(p).to_bytes(3, "big")
        try:
            out[free.name] = bytes(raw).rstrip(b"\x00").decode("utf-8")
        except UnicodeDecodeError:
            raise ValueError(f"{free.name}: not UTF-8") from None
    return out


def _decode_one(a: Arg, p: float) -> Any:
    if a.kind is bool:
        if p not in (0.0, 1.0):
            raise ValueError(f"{a.name}: expected 0 or 1, got {p!r}")
        return p == 1.0
    if a.kind is str:
        assert a.choices is not None
        if not (math.isfinite(p) and p.is_integer() and 0 <= p < len(a.choices)):
            raise ValueError(f"{a.name}: choice index {p!r} out of range 0..{len(a.choices) - 1}")
        return a.choices[int(p)]
    return p  # int/float: the dispatcher converts and range-checks


def parse_cli_value(a: Arg, text: str) -> Any:
    """An argument from its command-line spelling (``safer-ground send``)."""
    if a.kind is bool:
        low = text.strip().lower()
        if low in ("1", "true", "yes", "on"):
            return True
        if low in ("0", "false", "no", "off"):
            return False
        raise ValueError(f"{a.name}: expected true/false, got {text!r}")
    if a.kind is int:
        try:
            return int(text, 0)
        except ValueError:
            raise ValueError(f"{a.name}: expected an integer, got {text!r}") from None
    if a.kind is float:
        try:
            return float(text)
        except ValueError:
            raise ValueError(f"{a.name}: expected a number, got {text!r}") from None
    return text
