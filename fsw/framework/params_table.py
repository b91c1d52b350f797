"""The configuration reference, generated from the declarations (``param`` fields).

Every key of a configuration dataclass tree becomes one row: its dotted name, type, default,
units, bounds or choices and description. The description is the field's ``doc``; where a
field has none, the comment beside the key in the annotated TOML file (``key = value  # ...``)
stands in. ``safer-fsw config-keys`` prints the Markdown page ``docs/config.md`` is made of, and
a test checks the committed page is current, so the table is never kept by hand twice.
"""

from __future__ import annotations

import dataclasses
import re
import types
import typing
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

_KEY_RE = re.compile(r"^\s*([A-Za-z_][\w]*)\s*=.*?#\s*(.+?)\s*$")
_SECTION_RE = re.compile(r"^\s*\[\[?\s*([\w.]+)\s*\]\]?")


@dataclass(frozen=True)
class KeyDoc:
    """One configuration key as the reference shows it."""

    section: str
    key: str
    type: str
    default: str
    units: str
    bounds: str
    doc: str


def toml_comments(path: str | Path) -> dict[str, str]:
    """``{"section.key": comment}`` of the ``key = value  # comment`` lines of a TOML file."""
    out: dict[str, str] = {}
    section = ""
    for line in Path(path).read_text(encoding="utf-8").splitlines():
        s = _SECTION_RE.match(line)
        if s:
            section = s.group(1)
            continue
        k = _KEY_RE.match(line)
        if k:
            out.setdefault(f"{section}.{k.group(1)}", k.group(2))
    return out


def _type_name(t: Any) -> str:
    origin = typing.get_origin(t)
    if origin is None:
        return getattr(t, "__name__", str(t))
    args = [("..." if a is Ellipsis else _type_name(a)) for a in typing.get_args(t)]
    if origin is typing.Union or origin is types.UnionType:
        return " or ".join(args)
    return f"{getattr(origin, '__name__', str(origin))}[{', '.join(args)}]"


def _fmt(v: Any) -> str:
    if v is None:
        return "none"
    if isinstance(v, str):
        return f'"{v}"'
    if isinstance(v, float):
        return f"{v:g}"
    if isinstance(v, tuple):
        return "[" + ", ".join(_fmt(x) for x in v) + "]"
    return str(v)


def _default(f: dataclasses.Field[Any]) -> str:
    if f.default is not dataclasses.MISSING:
        return _fmt(f.default)
    if f.default_factory is not dataclasses.MISSING:
        value = f.default_factory()
        return "(table)" if dataclasses.is_dataclass(value) else _fmt(value)
    return "required"


def _bounds(meta: Mapping[str, Any]) -> str:
    if meta.get("choices"):
        return "one of " + ", ".join(_fmt(c) for c in meta["choices"])
    lo, hi = meta.get("lo"), meta.get("hi")
    if lo is not None and hi is not None:
        return f"{_fmt(lo)} .. {_fmt(hi)}"
    if lo is not None:
        return f">= {_fmt(lo)}"
    if hi is not None:
        return f"<= {_fmt(hi)}"
    return ""


def config_keys(cls: type, comments: Mapping[str, str] | None = None, prefix: str = "") -> list[KeyDoc]:
    """Every key under the dataclass ``cls``, depth first, nested tables as dotted sections."""
    notes = comments or {}
    hints = typing.get_type_hints(cls)
    rows: list[KeyDoc] = []
    for f in dataclasses.fields(cls):
        t = hints[f.name]
        if dataclasses.is_dataclass(t) and isinstance(t, type):
            rows += config_keys(t, notes, f"{prefix}{f.name}.")
            continue
        section = prefix.rstrip(".")
        meta = f.metadata
        doc = meta.get("doc") or notes.get(f"{section}.{f.name}", "")
        rows.append(KeyDoc(section, f.name, _type_name(t), _default(f), meta.get("units", ""), _bounds(meta), doc))
    return rows


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def markdown(cls: type, comments: Mapping[str, str] | None = None, title: str = "Configuration keys",
             intro: str = "") -> str:
    """The reference page: one table per section, in declaration order."""
    rows = config_keys(cls, comments)
    lines = [f"# {title}", ""]
    if intro:
        lines += [intro, ""]
    sections = list(dict.fromkeys(r.section for r in rows))
    named = [s for s in sections if s]
    if named:
        lines += ["Sections: " + ", ".join(f"[`[{s}]`](#{s.replace('.', '')})" for s in named), ""]
    for s in sections:
        lines += [f"## {s or 'top level'}", "", "| key | type | default | units | allowed | what |",
                  "|---|---|---|---|---|---|"]
        for r in rows:
            if r.section == s:
                lines.append(f"| `{r.key}` | {_cell(r.type)} | {_cell(r.default)} | {_cell(r.units)} "
                             f"| {_cell(r.bounds)} | {_cell(r.doc)} |")
        lines.append("")
    return "\n".join(lines)
