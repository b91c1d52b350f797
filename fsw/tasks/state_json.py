"""Reading a checkpoint section back: typed, validated fields of a JSON object.

A checkpoint state is plain JSON (``fsw.tasks.mission_state``). The typed sections
(``MissionSection``, ``MotionSection``) read their fields through these helpers, so a value of
the wrong type, a missing key or a NaN count is a :class:`StateError` naming the key, never a
traceback further on. A key may be optional with a default: sections written by earlier builds,
before the field existed, still load.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TypeVar

JsonObject = dict[str, object]  # a checkpoint section: a JSON object, its values read by the helpers below
T = TypeVar("T")


class StateError(ValueError):
    """A checkpointed state that cannot be resumed (malformed or incompatible)."""


class _Missing:
    pass


MISSING = _Missing()


def _get(d: JsonObject, key: str, default: object) -> object:
    if key in d:
        return d[key]
    if isinstance(default, _Missing):
        raise StateError(f"{key}: missing")
    return default


def as_object(v: object, what: str) -> JsonObject:
    """``v`` as a JSON object (string keys), or ``StateError``."""
    if not isinstance(v, dict) or not all(isinstance(k, str) for k in v):
        raise StateError(f"{what}: not an object")
    return {str(k): x for k, x in v.items()}


def as_float(v: object, what: str) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float):
        raise StateError(f"{what}: not a number ({v!r})")
    return float(v)


def as_int(v: object, what: str) -> int:
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) or int(v) != v:
        raise StateError(f"{what}: not an integer ({v!r})")
    return int(v)


def as_str(v: object, what: str) -> str:
    if not isinstance(v, str):
        raise StateError(f"{what}: not a string ({v!r})")
    return v


def as_list(v: object, what: str) -> list[object]:
    if not isinstance(v, list | tuple):
        raise StateError(f"{what}: not a list")
    return list(v)


def floats(v: object, what: str, n: int | None = None) -> tuple[float, ...]:
    """A list of numbers (exactly ``n`` of them if given)."""
    out = tuple(as_float(x, what) for x in as_list(v, what))
    if n is not None and len(out) != n:
        raise StateError(f"{what}: {len(out)} numbers, expected {n}")
    return out


def pose3(v: object, what: str) -> tuple[float, float, float]:
    x, y, z = floats(v, what, 3)
    return x, y, z


def matrix(v: object, what: str, rows: int, cols: int) -> list[list[float]]:
    """A ``rows`` x ``cols`` matrix of numbers as nested lists."""
    out = [list(floats(r, what, cols)) for r in as_list(v, what)]
    if len(out) != rows:
        raise StateError(f"{what}: {len(out)} rows, expected {rows}")
    return out


def get_float(d: JsonObject, key: str, default: float | _Missing = MISSING) -> float:
    return as_float(_get(d, key, default), key)


def get_int(d: JsonObject, key: str, default: int | _Missing = MISSING) -> int:
    return as_int(_get(d, key, default), key)


def get_bool(d: JsonObject, key: str, default: bool | _Missing = MISSING) -> bool:
    v = _get(d, key, default)
    if not isinstance(v, bool):
        raise StateError(f"{key}: not true/false ({v!r})")
    return v


def get_str(d: JsonObject, key: str, default: str | _Missing = MISSING) -> str:
    return as_str(_get(d, key, default), key)


def get_opt_str(d: JsonObject, key: str) -> str | None:
    """An optional string (absent or null: None)."""
    v = d.get(key)
    return None if v is None else as_str(v, key)


def get_opt_float(d: JsonObject, key: str) -> float | None:
    v = d.get(key)
    return None if v is None else as_float(v, key)


def get_opt_int(d: JsonObject, key: str) -> int | None:
    v = d.get(key)
    return None if v is None else as_int(v, key)


def get_opt_object(d: JsonObject, key: str) -> JsonObject | None:
    v = d.get(key)
    return None if v is None else as_object(v, key)


def get_list(d: JsonObject, key: str, default: Sequence[object] | _Missing = MISSING) -> list[object]:
    return as_list(_get(d, key, default), key)
