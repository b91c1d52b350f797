"""The .tlog format: each record is an 8-byte big-endian Unix time in microseconds followed
by one raw MAVLink frame, exactly as sent or received (signature included).

This is the format of MAVProxy's and QGroundControl's telemetry logs, so pymavlink's
``mavlogdump.py``, ``mavutil.mavlink_connection("x.tlog")`` and MAVProxy read it. pymavlink's
``setup_logfile`` does nothing on UDP links, hence this writer. The writer takes an open
binary stream (the task opens the file); the reader validates framing and names the offset
of the first bad record.

A full or failing device (``ENOSPC``, ``EIO``, ...; ``fsw.framework.storage``) stops the writer:
it keeps ``last_error`` (one line) and counts the records it then drops, rather than tearing
record after record; every record written before stays readable (a torn last record is the
"damaged tail" :func:`read_tlog` reports and skips).
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO

from fsw.comm.mavlink_dialect import SIGNATURE_LEN, mavlink
from fsw.framework.storage import describe, is_disk_fault

_TS = struct.Struct(">Q")


class TlogError(ValueError):
    """The file is not a .tlog (or is corrupt at a stated offset)."""


class TlogWriter:
    """Appends records to a binary stream; counts what it wrote."""

    def __init__(self, stream: BinaryIO) -> None:
        self.stream = stream
        self.records = 0
        self.bytes = 0
        self.errors = 0
        self.dropped = 0  # records not written because the device failed earlier
        self.stopped = False  # a disk fault stopped the log
        self.last_error = ""  # one line: the last failure

    def write(self, unix_s: float, frame: bytes) -> bool:
        """Write one record; returns False (and counts) if the stream refused it or is stopped."""
        if self.stopped:
            self.dropped += 1
            return False
        try:
            self.stream.write(_TS.pack(max(0, int(unix_s * 1e6))) + bytes(frame))
        except (OSError, ValueError) as exc:
            self._failed(exc)
            return False
        self.records += 1
        self.bytes += 8 + len(frame)
        return True

    def flush(self) -> None:
        if self.stopped:
            return
        try:
            self.stream.flush()
        except (OSError, ValueError) as exc:
            self._failed(exc)

    def _failed(self, exc: BaseException) -> None:
        self.errors += 1
        self.last_error = describe(exc)
        if is_disk_fault(exc):
            self.stopped = True
            self.last_error += f"; logging stopped after {self.records} records"

    def close(self) -> None:
        try:
            self.stream.close()
        except (OSError, ValueError):
            self.errors += 1


def frame_length(buf: bytes, offset: int) -> int:
    """Length of the MAVLink frame starting at ``buf[offset]``; raises TlogError."""
    if offset + 3 > len(buf):
        raise TlogError(f"offset {offset}: truncated frame header")
    magic, plen = buf[offset], buf[offset + 1]
    if magic == mavlink.PROTOCOL_MARKER_V2:
        signed = buf[offset + 2] & mavlink.MAVLINK_IFLAG_SIGNED
        return 10 + plen + 2 + (SIGNATURE_LEN if signed else 0)
    if magic == mavlink.PROTOCOL_MARKER_V1:
        return 6 + plen + 2
    raise TlogError(f"offset {offset}: no MAVLink frame marker (0x{magic:02x})")


def iter_records(data: bytes) -> Iterator[tuple[float, bytes]]:
    """``(unix_s, frame)`` for every record of a .tlog image; raises TlogError on bad framing."""
    pos = 0
    while pos < len(data):
        if pos + 8 > len(data):
            raise TlogError(f"offset {pos}: truncated record timestamp")
        (t_us,) = _TS.unpack_from(data, pos)
        n = frame_length(data, pos + 8)
        if pos + 8 + n > len(data):
            raise TlogError(f"offset {pos}: truncated frame ({n} bytes announced)")
        yield t_us / 1e6, data[pos + 8:pos + 8 + n]
        pos += 8 + n


def read_tlog(path: str | Path) -> tuple[list[tuple[float, bytes]], str | None]:
    """The records of a .tlog file and a note on a damaged tail (None if the file is whole).

    A file whose first record is bad is not a .tlog: TlogError with a one-line reason. A
    bad record later (e.g. the writer was killed mid-record) ends the list and is reported.
    """
    p = Path(path)
    try:
        data = p.read_bytes()
    except FileNotFoundError:
        raise TlogError(f"{p}: file not found") from None
    except IsADirectoryError:
        raise TlogError(f"{p}: is a directory") from None
    except OSError as exc:
        raise TlogError(f"{p}: unreadable ({exc.strerror or exc})") from None
    if not data:
        raise TlogError(f"{p}: empty file")
    records: list[tuple[float, bytes]] = []
    try:
        for rec in iter_records(data):
            records.append(rec)
    except TlogError as exc:
        if not records:
            raise TlogError(f"{p}: not a .tlog ({exc})") from None
        return records, f"{p}: stopped at a damaged record ({exc})"
    return records, None
