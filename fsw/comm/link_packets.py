"""Packet formats of the map link (docs/algorithm.md §6.6; byte tables in docs/link.md).

Every packet is one datagram: a 4-byte header, a body that depends on the type, and a
CRC-32 (``zlib.crc32``, the IEEE 802.3 polynomial) of everything before it::

    off  size  field
    0    1     magic 0xA5
    1    1     version (high nibble, 1) | type (low nibble)
    2    2     session id (u16, little-endian)
    4    n     body
    4+n  4     CRC-32 of bytes 0 .. 4+n

:func:`decode` returns a typed packet or raises :class:`PacketError` with a one-line
reason; the protocol counts those and drops the datagram. Nothing here keeps state.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass
from enum import IntEnum

MAGIC = 0xA5
VERSION = 1
HEADER_BYTES = 4
CRC_BYTES = 4
DATA_OVERHEAD = HEADER_BYTES + 4 + CRC_BYTES  # header, seq, serial, CRC
MAX_SEGMENTS = 0xFFFF
SHA256_BYTES = 32


class PacketError(ValueError):
    """A datagram that is not a valid link packet."""


class Ptype(IntEnum):
    OFFER = 1
    ACCEPT = 2
    REJECT = 3
    DATA = 4
    STATUS = 5
    PING = 6
    FIN = 7
    FIN_ACK = 8
    NO_SESSION = 9


class RejectReason(IntEnum):
    TOO_LARGE = 1
    BAD_PARAMETERS = 2


class FinStatus(IntEnum):
    VERIFIED = 0
    HASH_MISMATCH = 1


@dataclass(frozen=True)
class Offer:
    session: int
    map_id: int
    size: int
    segment_bytes: int
    sha256: bytes

    @property
    def n_segments(self) -> int:
        return -(-self.size // self.segment_bytes)


@dataclass(frozen=True)
class Accept:
    session: int
    map_id: int


@dataclass(frozen=True)
class Reject:
    session: int
    map_id: int
    reason: RejectReason


@dataclass(frozen=True)
class Data:
    session: int
    seq: int
    serial: int  # transmission counter (mod 2**16): echoed by STATUS for loss detection
    payload: bytes


@dataclass(frozen=True)
class Status:
    """Selective acknowledgement: segments ``< cum`` all held; ``bitmap`` bit ``i`` (LSB
    first) = segment ``cum + i`` held; ``highest`` = 1 + highest segment held."""

    session: int
    cum: int
    highest: int
    n_received: int
    echo_serial: int | None
    bitmap: bytes


@dataclass(frozen=True)
class Ping:
    session: int
    serial: int
    all_sent: bool  # every segment has been transmitted at least once


@dataclass(frozen=True)
class Fin:
    session: int
    map_id: int
    status: FinStatus


@dataclass(frozen=True)
class FinAck:
    session: int
    map_id: int


@dataclass(frozen=True)
class NoSession:
    """Receiver to sender: "I hold no session ``session``" (the answer to its DATA or PING
    after the receiver restarted or dropped the session); the sender offers again."""

    session: int


Packet = Offer | Accept | Reject | Data | Status | Ping | Fin | FinAck | NoSession

# Which end a packet is for: the sending end takes the receiver's answers, the receiving end
# the rest (an agent that both sends and receives demultiplexes on this; fsw.comm.link_peer).
TO_SENDER = frozenset({Ptype.ACCEPT, Ptype.REJECT, Ptype.STATUS, Ptype.FIN, Ptype.NO_SESSION})

_OFFER = struct.Struct("<IIH32s")
_ID = struct.Struct("<I")
_REJECT = struct.Struct("<IB")
_DATA = struct.Struct("<HH")
_STATUS = struct.Struct("<HHHHBB")
_PING = struct.Struct("<HB")
_FIN = struct.Struct("<IB")


def _frame(ptype: Ptype, session: int, body: bytes) -> bytes:
    head = struct.pack("<BBH", MAGIC, (VERSION << 4) | int(ptype), session & 0xFFFF)
    msg = head + body
    return msg + struct.pack("<I", zlib.crc32(msg))


def encode(p: Packet) -> bytes:
    """The datagram of a packet."""
    if isinstance(p, Data):
        return _frame(Ptype.DATA, p.session, _DATA.pack(p.seq, p.serial & 0xFFFF) + p.payload)
    if isinstance(p, Status):
        echo = 0 if p.echo_serial is None else p.echo_serial & 0xFFFF
        body = _STATUS.pack(p.cum, p.highest, p.n_received, echo,
                            0 if p.echo_serial is None else 1, len(p.bitmap))
        return _frame(Ptype.STATUS, p.session, body + p.bitmap)
    if isinstance(p, Ping):
        return _frame(Ptype.PING, p.session, _PING.pack(p.serial & 0xFFFF, int(p.all_sent)))
    if isinstance(p, Offer):
        return _frame(Ptype.OFFER, p.session,
                      _OFFER.pack(p.map_id, p.size, p.segment_bytes, p.sha256))
    if isinstance(p, Accept):
        return _frame(Ptype.ACCEPT, p.session, _ID.pack(p.map_id))
    if isinstance(p, Reject):
        return _frame(Ptype.REJECT, p.session, _REJECT.pack(p.map_id, int(p.reason)))
    if isinstance(p, Fin):
        return _frame(Ptype.FIN, p.session, _FIN.pack(p.map_id, int(p.status)))
    if isinstance(p, FinAck):
        return _frame(Ptype.FIN_ACK, p.session, _ID.pack(p.map_id))
    if isinstance(p, NoSession):
        return _frame(Ptype.NO_SESSION, p.session, b"")
    raise TypeError(f"not a packet: {p!r}")


def packet_type(datagram: bytes) -> Ptype | None:
    """The type nibble of a datagram, unchecked (None if it names no type): for routing only;
    :func:`decode` still checks the whole packet."""
    if len(datagram) < 2:
        return None
    try:
        return Ptype(datagram[1] & 0x0F)
    except ValueError:
        return None


def decode(datagram: bytes) -> Packet:
    """Parse and check one datagram; raises :class:`PacketError`."""
    n = len(datagram)
    if n < HEADER_BYTES + CRC_BYTES:
        raise PacketError(f"runt datagram of {n} bytes")
    magic, vt, session = struct.unpack_from("<BBH", datagram)
    if magic != MAGIC:
        raise PacketError(f"bad magic 0x{magic:02x}")
    (crc,) = struct.unpack_from("<I", datagram, n - CRC_BYTES)
    if zlib.crc32(datagram[: n - CRC_BYTES]) != crc:
        raise PacketError("CRC-32 mismatch")
    if vt >> 4 != VERSION:
        raise PacketError(f"unsupported version {vt >> 4}")
    try:
        ptype = Ptype(vt & 0x0F)
    except ValueError:
        raise PacketError(f"unknown packet type {vt & 0x0F}") from None
    body = datagram[HEADER_BYTES: n - CRC_BYTES]
    try:
        return _parse(ptype, session, body)
    except struct.error:
        raise PacketError(f"{ptype.name} body of {len(body)} bytes is malformed") from None


def _parse(ptype: Ptype, session: int, body: bytes) -> Packet:
    if ptype is Ptype.DATA:
        seq, serial = _DATA.unpack_from(body)
        return Data(session, seq, serial, body[_DATA.size:])
    if ptype is Ptype.STATUS:
        cum, highest, nrx, echo, flags, nb = _STATUS.unpack_from(body)
        bitmap = body[_STATUS.size:]
        if len(bitmap) != nb or flags > 1 or cum > highest or nrx > highest:
            raise PacketError("STATUS fields are inconsistent")
        return Status(session, cum, highest, nrx, echo if flags & 1 else None, bitmap)
    _exact(ptype, body, {Ptype.PING: _PING.size, Ptype.OFFER: _OFFER.size, Ptype.ACCEPT: 4,
                         Ptype.REJECT: _REJECT.size, Ptype.FIN: _FIN.size, Ptype.FIN_ACK: 4,
                         Ptype.NO_SESSION: 0})
    if ptype is Ptype.NO_SESSION:
        return NoSession(session)
    if ptype is Ptype.PING:
        serial, flags = _PING.unpack(body)
        if flags > 1:
            raise PacketError("PING flags are invalid")
        return Ping(session, serial, bool(flags))
    if ptype is Ptype.OFFER:
        map_id, size, seg, digest = _OFFER.unpack(body)
        if size < 1 or seg < 1 or -(-size // seg) > MAX_SEGMENTS:
            raise PacketError(f"OFFER of {size} bytes in {seg}-byte segments is impossible")
        return Offer(session, map_id, size, seg, digest)
    if ptype is Ptype.ACCEPT:
        return Accept(session, _ID.unpack(body)[0])
    if ptype is Ptype.REJECT:
        map_id, reason = _REJECT.unpack(body)
        try:
            return Reject(session, map_id, RejectReason(reason))
        except ValueError:
            raise PacketError(f"unknown reject reason {reason}") from None
    if ptype is Ptype.FIN:
        map_id, status = _FIN.unpack(body)
        try:
            return Fin(session, map_id, FinStatus(status))
        except ValueError:
            raise PacketError(f"unknown FIN status {status}") from None
    return FinAck(session, _ID.unpack(body)[0])


def _exact(ptype: Ptype, body: bytes, sizes: dict[Ptype, int]) -> None:
    if len(body) != sizes[ptype]:
        raise PacketError(f"{ptype.name} body has {len(body)} bytes, expected {sizes[ptype]}")
