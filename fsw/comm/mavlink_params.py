"""The flight configuration as MAVLink parameters (the PARAM protocol of a stock ground station).

Every numeric or boolean key of the configuration (``config/fsw.toml``; tables of tables
followed, lists of tables such as ``executive.tasks`` left out) is one parameter. MAVLink
names a parameter with at most 16 characters, so each key gets a short id
(:func:`param_id`): the section's short name (:data:`SECTION_IDS`, else its first four
letters), ``_``, the key upper-cased; when that is longer than 16 characters, the key's words
are cut to their first three letters, then the id is cut at 16 and, if two keys still meet,
ends in ``~`` and a letter. ``safer-ground params`` (docs/ground.md) prints the table
``id = section.key``; the ids depend only on the configuration's schema, never on values.

Values travel as PARAM_VALUE ``param_value`` (a float32): floats as REAL32, integers and
booleans as INT32 by value (a float32 holds integers exactly up to 2**24; larger ones are
rounded on the wire, and PARAM_SET of such a key is refused). Sans-I/O: builds messages and
parses PARAM_SET values; deciding whether a set applies is the owner's (``fsw.tasks.mavlink_gcs``).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

from fsw.comm.mavlink_dialect import mavlink

ID_LEN = 16
EXACT_INT = 2**24
SECTION_IDS = {"mavlink": "MAV", "executive": "EXEC", "localization": "LOC", "registration": "REG",
               "geofence": "FENCE", "calibration": "CAL", "checkpoint": "CKPT", "devices": "DEV"}


@dataclass(frozen=True)
class Param:
    """One parameter: its id, the config path ``(section, ..., key)``, its kind and index."""

    pid: str
    path: tuple[str, ...]
    kind: type
    index: int

    @property
    def key(self) -> str:
        return ".".join(self.path)

    @property
    def mav_type(self) -> int:
        return mavlink.MAV_PARAM_TYPE_REAL32 if self.kind is float else mavlink.MAV_PARAM_TYPE_INT32


def leaves(cfg: Any, path: tuple[str, ...] = ()) -> list[tuple[tuple[str, ...], type]]:
    """``(path, kind)`` of every int/float/bool field of a dataclass tree, in declared order."""
    out: list[tuple[tuple[str, ...], type]] = []
    for f in dataclasses.fields(cfg):
        v = getattr(cfg, f.name)
        if dataclasses.is_dataclass(v) and not isinstance(v, type):
            out += leaves(v, path + (f.name,))
        elif isinstance(v, (bool, int, float)):
            out.append((path + (f.name,), type(v)))
    return out


def param_id(path: tuple[str, ...]) -> str:
    """The short id of a config path (module docstring), before collisions are resolved."""
    head = path[0]
    prefix = "_".join([SECTION_IDS.get(head, head[:4].upper())] + [p[:4].upper() for p in path[1:-1]])
    words = path[-1].upper().split("_")
    pid = f"{prefix}_{'_'.join(words)}"
    if len(pid) > ID_LEN:
        pid = f"{prefix}_{'_'.join(w[:3] for w in words)}"
    return pid[:ID_LEN].rstrip("_")


def build_table(cfg: Any) -> list[Param]:
    """Every parameter of ``cfg`` with a unique id (module docstring), index = position."""
    out: list[Param] = []
    used: set[str] = set()
    for i, (path, kind) in enumerate(leaves(cfg)):
        pid = param_id(path)
        n = 0
        while pid in used:
            pid = f"{param_id(path)[:ID_LEN - 2]}~{chr(ord('A') + n % 26)}"
            n += 1
        used.add(pid)
        out.append(Param(pid, path, kind, i))
    return out


def value_of(cfg: Any, p: Param) -> Any:
    v = cfg
    for name in p.path:
        v = getattr(v, name)
    return v


def wire_value(value: Any) -> float:
    """The float32 value a PARAM_VALUE carries (bool as 0/1; inf/NaN as they are)."""
    return float(int(value)) if isinstance(value, bool) else float(value)


def param_value(p: Param, value: Any, count: int) -> mavlink.MAVLink_param_value_message:
    return mavlink.MAVLink_param_value_message(p.pid.encode(), wire_value(value), p.mav_type, count, p.index)


def from_wire(p: Param, value: float) -> Any:
    """The config value a PARAM_SET asks for; raises ``ValueError`` with the reason."""
    if not math.isfinite(value):
        raise ValueError(f"{p.pid}: {value} is not a finite number")
    if p.kind is float:
        return float(value)
    if not float(value).is_integer():
        raise ValueError(f"{p.pid}: {value} is not an integer")
    if p.kind is bool:
        if value not in (0.0, 1.0):
            raise ValueError(f"{p.pid}: a switch is 0 or 1, got {value}")
        return value == 1.0
    if abs(value) >= EXACT_INT:
        raise ValueError(f"{p.pid}: {value:.0f} cannot travel exactly in a float32; edit the config file")
    return int(value)


def decode_id(raw: Any) -> str:
    """A PARAM_* ``param_id`` field (bytes or str, NUL padded) as text."""
    if isinstance(raw, bytes):
        raw = raw.decode("utf-8", "replace")
    return str(raw).split("\x00", 1)[0]
