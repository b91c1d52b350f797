"""Non-volatile store of the MAVLink signing replay window (newest timestamp per stream).

Without it a restart forgets which timestamps each signed stream ``(link_id, system,
component)`` has used, and a recorded command less than ``signing_max_age_s`` old could be
replayed once. The window is a small JSON file written atomically (temporary file in the same
directory, flush + fsync, ``os.replace``, fsync of the directory), as the map checkpoints
are (``fsw.drivers.map_store``), so a power cut leaves the old window or the new one.

Loading never raises: a missing file is an empty window; an unreadable or malformed one is an
empty window *and* a reason the caller reports (the ``signing_max_age_s`` check still refuses
every command older than that, so the exposure is bounded).
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

Stream = tuple[int, int, int]
VERSION = 1


def default_path(key_file: str) -> Path:
    """``KEY_FILE.replay.json``: the window belongs to the key (a new key starts a new window)."""
    return Path(f"{key_file}.replay.json")


def load(path: str | Path) -> tuple[dict[Stream, int], str | None]:
    """``(window, problem)``; ``problem`` is None when the file was read (or does not exist yet)."""
    p = Path(path)
    try:
        doc = json.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        return {}, None
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        return {}, f"{p}: unreadable ({exc})"
    if not isinstance(doc, dict) or doc.get("version") != VERSION or not isinstance(doc.get("streams"), list):
        return {}, f"{p}: not a version {VERSION} replay window"
    out: dict[Stream, int] = {}
    for row in doc["streams"]:
        ok = isinstance(row, list) and len(row) == 4 and all(type(v) is int for v in row)
        if not ok or not (0 <= row[0] < 256 and 0 <= row[1] < 256 and 0 <= row[2] < 256 and 0 <= row[3] < 2**48):
            return {}, f"{p}: malformed stream entry {row!r}"
        out[(row[0], row[1], row[2])] = row[3]
    return out, None


def save(path: str | Path, streams: dict[Stream, int]) -> None:
    """Write the window atomically; raises ``OSError`` (the caller events it and retries later)."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    rows = [[*k, v] for k, v in sorted(streams.items())]
    text = json.dumps({"version": VERSION, "streams": rows}, indent=0)
    fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".tmp", dir=p.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, 0o600)
        os.replace(tmp, p)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    try:
        dfd = os.open(p.parent, os.O_RDONLY)
    except OSError:
        return  # e.g. a platform without directory fds: the rename is done, only durability waits
    try:
        os.fsync(dfd)
    finally:
        os.close(dfd)
