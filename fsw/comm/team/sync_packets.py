"""Packets of the two-way map sync (docs/sync.md; the protocol: ``fsw.comm.team.map_sync``).

They share the map link's framing (``fsw.comm.link_packets``: magic 0xA5, version 1, a type
nibble, a 16-bit word, the body, a CRC-32 of everything before it) with type numbers that
neither the map link (1-9) nor the fix packets (12-14) use, so one radio carries all three and
a receiver tells them apart by the type nibble. The 16-bit word names the sending agent (high
byte) and the map frame (low byte); every body starts with the sender's transmission serial
(u16), so a copy the protocol sent again differs from a copy the channel duplicated.

TILE (10): ``serial`` u16, ``owner`` u8 (whose map layer), ``tile`` u16, ``version`` u32,
``digest`` u32 (:func:`blob_digest`: 4 bytes of BLAKE2b of the tile's codec bytes), then the tile's codec container
(``fsw.core.codec.mapcodec``), which decodes alone.

DIGEST (11): ``serial`` u16, ``boot`` u16, ``dseq`` u16 (this digest's number), ``echo_dseq``
u16 (the peer's last digest received), ``echo_serial`` u16 (the peer's last packet received),
``flags`` u8 (bit 0: send me your holdings of my layer; bit 1: answer with a digest now; bit 2:
the ack list is cut short; bit 3: an echo is valid; bit 4: started with no replica),
``held_count`` u16, ``held_hash`` 8 bytes (:meth:`~fsw.comm.team.map_sync.MapSync.layer_hash` of
the sender's copy of the receiver's layer), ``n_acks`` u8 and ``n_acks`` x (``tile`` u16,
``version`` u16: the low 16 bits), ``n_wants`` u8 and ``n_wants`` x ``tile`` u16 (tiles of the sender's own layer
it asks to be given back).

HOLDINGS (15): ``serial`` u16, ``set_id`` u16, ``page`` u8, ``n_pages`` u8, then entries
(``tile`` u16, ``version`` u32, ``digest`` u32) of the sender's copy of the receiver's layer,
for the tiles ``page * per`` up to ``(page + 1) * per`` (``per`` entries fit the MTU).

:func:`decode` raises :class:`~fsw.comm.link_packets.PacketError` with a one-line reason.
"""

from __future__ import annotations

import hashlib
import struct
import zlib
from dataclasses import dataclass

from fsw.comm.link_packets import MAGIC, VERSION, PacketError

TILE, DIGEST, HOLDINGS = 10, 11, 15
SYNC_TYPES = frozenset({TILE, DIGEST, HOLDINGS})
FRAME_BYTES = 8  # header 4 + CRC 4
_TILE = struct.Struct("<HBHII")
_DIGEST = struct.Struct("<HHHHHBH8sB")
_ACK = struct.Struct("<HH")
_HOLD = struct.Struct("<HHBB")
_ENTRY = struct.Struct("<HII")
TILE_OVERHEAD = FRAME_BYTES + _TILE.size
DIGEST_BASE = FRAME_BYTES + _DIGEST.size + 1
ACK_BYTES, WANT_BYTES, ENTRY_BYTES = _ACK.size, 2, _ENTRY.size
HOLDINGS_BASE = FRAME_BYTES + _HOLD.size

WANT_HOLDINGS, ANSWER_NOW, ACKS_CUT, ECHO_VALID, FRESH = 1, 2, 4, 8, 16


@dataclass(frozen=True)
class Tile:
    agent: int  # the sender
    frame: int
    serial: int
    owner: int  # whose layer the tile belongs to
    tile: int
    version: int
    digest: int
    blob: bytes


@dataclass(frozen=True)
class Digest:
    agent: int
    frame: int
    serial: int
    boot: int
    dseq: int
    echo_dseq: int
    echo_serial: int
    flags: int
    held_count: int
    held_hash: bytes
    acks: tuple[tuple[int, int], ...]
    wants: tuple[int, ...]


@dataclass(frozen=True)
class Holdings:
    agent: int
    frame: int
    serial: int
    set_id: int
    page: int
    n_pages: int
    entries: tuple[tuple[int, int, int], ...]  # (tile, version, digest)


SyncPacket = Tile | Digest | Holdings


def blob_digest(blob: bytes) -> int:
    """A tile's content digest. (Not CRC-32: a codec container ends with its own CRC-32, and the
    CRC-32 of any such message is the same constant.)"""
    return int.from_bytes(hashlib.blake2b(blob, digest_size=4).digest(), "little")


def _frame(ptype: int, agent: int, frame: int, body: bytes) -> bytes:
    msg = struct.pack("<BBBB", MAGIC, (VERSION << 4) | ptype, frame & 0xFF, agent & 0xFF) + body
    return msg + struct.pack("<I", zlib.crc32(msg))


def encode(p: SyncPacket) -> bytes:
    if isinstance(p, Tile):
        return _frame(TILE, p.agent, p.frame, _TILE.pack(p.serial & 0xFFFF, p.owner, p.tile, p.version,
                                                          p.digest) + p.blob)
    if isinstance(p, Digest):
        head = _DIGEST.pack(p.serial & 0xFFFF, p.boot & 0xFFFF, p.dseq & 0xFFFF, p.echo_dseq & 0xFFFF,
                            p.echo_serial & 0xFFFF, p.flags, p.held_count, p.held_hash, len(p.acks))
        acks = b"".join(_ACK.pack(t, v & 0xFFFF) for t, v in p.acks)
        wants = struct.pack(f"<B{len(p.wants)}H", len(p.wants), *p.wants)
        return _frame(DIGEST, p.agent, p.frame, head + acks + wants)
    body = _HOLD.pack(p.serial & 0xFFFF, p.set_id & 0xFFFF, p.page, p.n_pages)
    return _frame(HOLDINGS, p.agent, p.frame, body + b"".join(_ENTRY.pack(*e) for e in p.entries))


def is_sync_packet(datagram: bytes) -> bool:
    """Whether a datagram's header names a sync type (the routing test; integrity is decode's)."""
    return len(datagram) >= 2 and datagram[0] == MAGIC and (datagram[1] & 0xF) in SYNC_TYPES


def decode(datagram: bytes) -> SyncPacket:
    d = bytes(datagram)
    if len(d) < FRAME_BYTES + 2:
        raise PacketError(f"sync packet of {len(d)} bytes is too short")
    if d[0] != MAGIC or d[1] >> 4 != VERSION:
        raise PacketError("not a version-1 link packet")
    if struct.unpack("<I", d[-4:])[0] != zlib.crc32(d[:-4]):
        raise PacketError("sync packet CRC mismatch")
    ptype, frame, agent, body = d[1] & 0xF, d[2], d[3], d[4:-4]
    try:
        if ptype == TILE:
            serial, owner, tile, version, digest = _TILE.unpack_from(body)
            blob = body[_TILE.size:]
            if not blob or blob_digest(blob) != digest:
                raise PacketError("TILE digest does not match its bytes")
            return Tile(agent, frame, serial, owner, tile, version, digest, blob)
        if ptype == DIGEST:
            return _digest(agent, frame, body)
        if ptype == HOLDINGS:
            serial, set_id, page, n_pages = _HOLD.unpack_from(body)
            rest = body[_HOLD.size:]
            if len(rest) % _ENTRY.size or page >= n_pages:
                raise PacketError("HOLDINGS page is malformed")
            entries = tuple(_ENTRY.unpack_from(rest, i) for i in range(0, len(rest), _ENTRY.size))
            return Holdings(agent, frame, serial, set_id, page, n_pages, entries)
    except struct.error:
        raise PacketError(f"sync packet type {ptype} with a {len(body)}-byte body is malformed") from None
    raise PacketError(f"type {ptype} is not a sync packet")


def _digest(agent: int, frame: int, body: bytes) -> Digest:
    serial, boot, dseq, echo_dseq, echo_serial, flags, held_count, held_hash, n_acks = _DIGEST.unpack_from(body)
    off = _DIGEST.size
    acks = tuple(_ACK.unpack_from(body, off + i * _ACK.size) for i in range(n_acks))
    off += n_acks * _ACK.size
    (n_wants,) = struct.unpack_from("<B", body, off)
    wants = struct.unpack_from(f"<{n_wants}H", body, off + 1)
    if off + 1 + 2 * n_wants != len(body) or flags > 31:
        raise PacketError("DIGEST fields are inconsistent")
    return Digest(agent, frame, serial, boot, dseq, echo_dseq, echo_serial, flags, held_count, held_hash, acks,
                  tuple(wants))
