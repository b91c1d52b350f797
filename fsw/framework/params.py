"""Typed, validated, frozen configuration loaded from TOML.

Each subsystem declares its configuration as a frozen dataclass next to the code that uses
it; :func:`build` turns a TOML table into that dataclass and refuses anything it cannot
vouch for: a missing required key, an unknown key, a wrong type, a value out of range or a
number that is not finite (TOML allows ``nan``, ``inf`` and ``-inf``; NaN fails every range
comparison, so it is refused before any bound is checked, and an infinity is refused unless
the field declares ``allow_inf=True`` and documents what an infinite value means).
Every refusal is a :class:`ConfigError` that names the file, the dotted key and the reason
in one line, so a command-line tool can print it and exit 2 instead of a traceback.

Tables and arrays may nest at most :data:`MAX_DEPTH` levels (a file nested deeper is refused
before anything walks it, so no input reaches a ``RecursionError``). ``build(...,
complete=True)`` also refuses a key left out of a table (or of an element of an array of
tables) even when it has a default: a flight file is then the whole record of what flies.

Declaring a bounded field::

    @dataclass(frozen=True)
    class ExecutiveConfig:
        frame_period_s: float = param(0.1, lo=0.001, hi=10.0, units="s")
"""

from __future__ import annotations

import dataclasses
import functools
import math
import tomllib
import types
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Any, TypeVar

T = TypeVar("T")

_MISSING = dataclasses.MISSING
MAX_DEPTH = 32  #: deepest nesting of tables and arrays a configuration file may have


class ConfigError(ValueError):
    """A configuration problem, reported as ``file: key: reason`` on one line."""

    def __init__(self, source: str, key: str, reason: str) -> None:
        self.source = source
        self.key = key
        self.reason = reason
        super().__init__(f"{source}: {key or '<top>'}: {reason}")


def param(
    default: Any = _MISSING,
    *,
    lo: float | None = None,
    hi: float | None = None,
    choices: tuple[Any, ...] | None = None,
    units: str = "",
    doc: str = "",
    allow_inf: bool = False,
) -> Any:
    """A dataclass field with bounds, allowed choices, units and a description.

    Leave ``default`` out to make the key required in the file. Numbers must be finite;
    ``allow_inf=True`` admits ``inf``/``-inf`` (say in ``doc`` what infinity means, e.g.
    "none"); NaN is never admitted.
    """
    meta = {"lo": lo, "hi": hi, "choices": choices, "units": units, "doc": doc, "allow_inf": allow_inf}
    if default is _MISSING:
        return dataclasses.field(metadata=meta)
    if isinstance(default, (list, dict, set)):
        raise TypeError("use a tuple or a default_factory for mutable defaults")
    return dataclasses.field(default=default, metadata=meta)


def load_toml(path: str | Path) -> dict[str, Any]:
    """Read a TOML file, turning I/O and syntax errors into :class:`ConfigError`."""
    p = Path(path)
    try:
        with p.open("rb") as fh:
            data = tomllib.load(fh)
    except RecursionError:  # the parser itself recurses on nested arrays and inline tables
        raise ConfigError(str(p), "", f"nested deeper than {MAX_DEPTH} levels") from None
    except FileNotFoundError:
        raise ConfigError(str(p), "", "file not found") from None
    except IsADirectoryError:
        raise ConfigError(str(p), "", "is a directory, not a file") from None
    except PermissionError:
        raise ConfigError(str(p), "", "permission denied") from None
    except OSError as exc:
        raise ConfigError(str(p), "", f"unreadable ({exc.strerror or exc})") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(str(p), "", f"not valid TOML ({exc})") from None
    except UnicodeDecodeError:
        raise ConfigError(str(p), "", "not UTF-8 text") from None
    check_depth(data, str(p))
    return data


def check_depth(data: Any, source: str, limit: int = MAX_DEPTH) -> None:
    """Refuse tables and arrays nested deeper than ``limit`` (walked without recursion)."""
    stack: list[tuple[Any, str, int]] = [(data, "", 0)]
    while stack:
        value, key, depth = stack.pop()
        if depth > limit:
            raise ConfigError(source, key, f"nested deeper than {limit} levels")
        if isinstance(value, Mapping):
            stack.extend((v, _join(key, str(k)), depth + 1) for k, v in value.items())
        elif isinstance(value, list):
            stack.extend((v, f"{key}[{i}]", depth + 1) for i, v in enumerate(value))


def load(cls: type[T], path: str | Path, section: str | None = None) -> T:
    """Load ``path`` (or one table of it) into the dataclass ``cls``."""
    data: Any = load_toml(path)
    if section is not None:
        if section not in data:
            raise ConfigError(str(path), section, "missing required table")
        data = data[section]
    return build(cls, data, source=str(path), prefix=section or "")


def build(cls: type[T], data: Any, source: str = "<config>", prefix: str = "", complete: bool = False) -> T:
    """Validate ``data`` against the dataclass ``cls`` and construct it; ``complete``: every key
    of every table must be present (a left-out key is refused rather than defaulted)."""
    if not isinstance(data, Mapping):
        raise ConfigError(source, prefix, f"expected a table, got {_tname(data)}")
    if not prefix:
        check_depth(data, source)
    hints = _hints(cls)  # type: ignore[arg-type]
    fields = {f.name: f for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    unknown = sorted(set(data) - set(fields))
    if unknown:
        key = _join(prefix, unknown[0])
        raise ConfigError(source, key, f"unknown key (allowed: {', '.join(sorted(fields))})")
    kwargs: dict[str, Any] = {}
    for name, f in fields.items():
        key = _join(prefix, name)
        if name not in data:
            if f.default is _MISSING and f.default_factory is _MISSING:
                raise ConfigError(source, key, "missing required key")
            if complete:
                what = "table" if dataclasses.is_dataclass(hints[name]) else "key"
                raise ConfigError(source, key, f"missing {what} (a flight configuration lists every key)")
            continue
        tp, args = hints[name], typing.get_args(hints[name])
        if complete and dataclasses.is_dataclass(tp):
            kwargs[name] = build(tp, data[name], source, key, complete=True)  # type: ignore[arg-type]
        elif complete and typing.get_origin(tp) is tuple and args and dataclasses.is_dataclass(args[0]) \
                and isinstance(data[name], list):  # an array of tables: every element complete too
            kwargs[name] = tuple(build(args[0], v, source, f"{key}[{i}]", complete=True)  # type: ignore[arg-type]
                                 for i, v in enumerate(data[name]))
        else:
            kwargs[name] = _convert(tp, data[name], source, key, bool(f.metadata.get("allow_inf")))
        _check_bounds(f.metadata, kwargs[name], source, key)
    try:
        return cls(**kwargs)
    except (ValueError, TypeError) as exc:  # __post_init__ cross-field checks
        raise ConfigError(source, prefix, str(exc)) from None


@functools.cache
def _hints(cls: type) -> dict[str, Any]:
    return typing.get_type_hints(cls)


def _convert(tp: Any, value: Any, source: str, key: str, allow_inf: bool = False) -> Any:
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if dataclasses.is_dataclass(tp):
        return build(tp, value, source, key)  # type: ignore[arg-type]
    if origin is typing.Literal:
        if value not in args:
            raise ConfigError(source, key, f"must be one of {list(args)}, got {value!r}")
        return value
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        alts = [a for a in args if a is not type(None)]
        if len(alts) == 1:  # Optional[X]: X's own error, with its exact key
            return _convert(alts[0], value, source, key, allow_inf)
        errors = []
        for alt in args:
            if alt is type(None):
                continue
            try:
                return _convert(alt, value, source, key, allow_inf)
            except ConfigError as exc:
                errors.append(exc.reason)
        raise ConfigError(source, key, " or ".join(errors))
    if origin is tuple:
        if not isinstance(value, list):
            raise ConfigError(source, key, f"expected an array, got {_tname(value)}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_convert(args[0], v, source, f"{key}[{i}]", allow_inf) for i, v in enumerate(value))
        if len(value) != len(args):
            raise ConfigError(source, key, f"expected {len(args)} elements, got {len(value)}")
        return tuple(
            _convert(a, v, source, f"{key}[{i}]", allow_inf) for i, (a, v) in enumerate(zip(args, value, strict=True))
        )
    if origin is dict:
        if not isinstance(value, Mapping):
            raise ConfigError(source, key, f"expected a table, got {_tname(value)}")
        return {str(k): _convert(args[1], v, source, _join(key, str(k)), allow_inf) for k, v in value.items()}
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(source, key, f"expected true or false, got {_tname(value)}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(source, key, f"expected an integer, got {_tname(value)}")
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(source, key, f"expected a number, got {_tname(value)}")
        return _finite(float(value), source, key, allow_inf)
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(source, key, f"expected a string, got {_tname(value)}")
        return value
    if tp is Any:
        _no_nan_inside(value, source, key)
        return value
    raise ConfigError(source, key, f"unsupported field type {tp!r}")  # a schema bug


def _check_bounds(meta: Mapping[str, Any], value: Any, source: str, key: str) -> None:
    lo, hi, choices = meta.get("lo"), meta.get("hi"), meta.get("choices")
    units = meta.get("units") or ""
    values = value if isinstance(value, tuple) else (value,)
    for v in values:
        if choices is not None and v not in choices:
            raise ConfigError(source, key, f"must be one of {list(choices)}, got {v!r}")
        if isinstance(v, (int, float)) and not isinstance(v, bool):
            if lo is not None and v < lo:
                raise ConfigError(source, key, f"{v} {units} is below the minimum {lo} {units}".replace("  ", " "))
            if hi is not None and v > hi:
                raise ConfigError(source, key, f"{v} {units} is above the maximum {hi} {units}".replace("  ", " "))


def _finite(v: float, source: str, key: str, allow_inf: bool) -> float:
    if math.isnan(v):
        raise ConfigError(source, key, "nan is not a number (a NaN passes no range check)")
    if math.isinf(v) and not allow_inf:
        raise ConfigError(source, key, f"{v} is not allowed (the value must be finite)")
    return v


def _no_nan_inside(value: Any, source: str, key: str) -> None:
    """Free-form (``Any``) values may hold numbers too: refuse NaN and infinities anywhere in them."""
    if isinstance(value, float):
        _finite(value, source, key, False)
    elif isinstance(value, Mapping):
        for k, v in value.items():
            _no_nan_inside(v, source, _join(key, str(k)))
    elif isinstance(value, list):
        for i, v in enumerate(value):
            _no_nan_inside(v, source, f"{key}[{i}]")


def describe(cls: type) -> list[dict[str, Any]]:
    """Rows (key, type, default, units, bounds, doc) describing a config dataclass."""
    rows = []
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        rows.append(
            {
                "key": f.name,
                "type": getattr(hints[f.name], "__name__", str(hints[f.name])),
                "default": None if f.default is _MISSING else f.default,
                **{k: v for k, v in f.metadata.items() if v},
            }
        )
    return rows


def _join(prefix: str, name: str) -> str:
    return f"{prefix}.{name}" if prefix else name


def _tname(v: Any) -> str:
    return {
        dict: "a table",
        list: "an array",
        str: "a string",
        bool: "a boolean",
        int: "an integer",
        float: "a number",
    }.get(type(v), type(v).__name__)


def check_field(cls: type, name: str, value: Any, source: str, key: str) -> Any:
    """One field's value checked as a config file's would be (type, range, choices); returns it
    converted, raises :class:`ConfigError`. The section's cross-field checks run when the
    caller builds the section (``dataclasses.replace``)."""
    f = {f.name: f for f in dataclasses.fields(cls)}.get(name)
    if f is None:
        raise ConfigError(source, key, "unknown key")
    out = _convert(_hints(cls)[name], value, source, key, bool(f.metadata.get("allow_inf")))
    _check_bounds(f.metadata, out, source, key)
    return out
