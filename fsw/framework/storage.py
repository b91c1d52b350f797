"""Storage faults in words: what a full disk or a failing device looks like to every writer.

Every writer of the flight software and the bench (map checkpoints, the .tlog, the Cliff-bot's
map, the run's pictures and summary) meets the same two faults, ``ENOSPC`` (the device is
full; ``EDQUOT`` is its quota twin) and ``EIO`` (the device failed), and answers them the same
way: one line naming the file and the fault (:func:`describe`), an event, and the last good
state kept (nothing half-written under a final name). :func:`probe` asks the device for room
before a run starts or resumes, so a disk that is still full is said in one line up front.
"""

from __future__ import annotations

import errno
import os
import tempfile
from pathlib import Path

#: errno values that mean "the storage device cannot take this write" (not a bug, not a bad path)
DISK_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EIO, errno.EROFS})


class StorageError(OSError):
    """A write refused by the storage device (full, failing or read-only); ``str`` is one line."""

    def __str__(self) -> str:
        return str(self.strerror)


def is_disk_fault(exc: BaseException) -> bool:
    """True for an ``OSError`` whose errno says the device is full, failing or read-only."""
    return isinstance(exc, OSError) and exc.errno in DISK_ERRNOS


def describe(exc: BaseException) -> str:
    """One line: the OS's words and the errno name, e.g. ``No space left on device (ENOSPC)``."""
    if isinstance(exc, OSError) and exc.errno is not None:
        name = errno.errorcode.get(exc.errno, str(exc.errno))
        where = f"{exc.filename}: " if exc.filename else ""
        return f"{where}{exc.strerror or os.strerror(exc.errno)} ({name})"
    if isinstance(exc, OSError) and "written" in str(exc):  # numpy's short write: the device took only part
        return f"short write, the device is full or failing ({exc})".replace("\n", " ")
    return f"{type(exc).__name__}: {exc}".replace("\n", " ")


def probe(directory: str | Path, need_bytes: int) -> None:
    """Write, fsync and remove ``need_bytes`` in ``directory`` (made if missing); raises
    :class:`StorageError` (one line) if the device refuses."""
    d = Path(directory)
    try:
        d.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=".probe_", suffix=".tmp", dir=d)
    except OSError as exc:
        raise StorageError(exc.errno, f"{d}: cannot write ({describe(exc)})") from None
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(bytes(max(1, need_bytes)))
            fh.flush()
            os.fsync(fh.fileno())
    except OSError as exc:
        raise StorageError(exc.errno, f"{d}: no room for {need_bytes} bytes ({describe(exc)})") from None
    finally:
        Path(tmp).unlink(missing_ok=True)
