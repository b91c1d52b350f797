"""Reading a .tlog for the ground tools: records -> ``(time, message, frame)``."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from fsw.comm.mavlink_dialect import new_codec
from fsw.comm.mavlink_tlog import TlogError, read_tlog


@dataclass(frozen=True)
class LoggedMessage:
    time_s: float  # Unix seconds of the record
    msg: Any
    frame: bytes


def load_messages(path: str | Path) -> tuple[list[LoggedMessage], str | None]:
    """Every decodable message of a .tlog and a note on damage (None if whole).

    Raises :class:`TlogError` when the file is not a .tlog or holds no MAVLink message.
    """
    records, note = read_tlog(path)
    parser = new_codec(255, 0)
    out: list[LoggedMessage] = []
    bad = 0
    for t, frame in records:
        try:
            msgs = parser.parse_buffer(frame) or []
        except Exception:  # noqa: BLE001 - a damaged record: count it, keep going
            parser = new_codec(255, 0)
            msgs = []
        good = [m for m in msgs if m.get_type() != "BAD_DATA"]
        bad += len(msgs) - len(good) + (0 if msgs else 1)
        out.extend(LoggedMessage(t, m, frame) for m in good)
    if not out:
        raise TlogError(f"{path}: no MAVLink message could be decoded")
    if bad:
        extra = f"{bad} record(s) failed to decode"
        note = f"{note}; {extra}" if note else f"{path}: {extra}"
    return out, note
