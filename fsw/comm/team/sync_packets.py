"""Packets of the two-way map sync (docs/sync.md; the protocol: ``fsw.comm.team.map_sync``).

They share the map link's framing (``fsw.comm.link_packets``: magic 0xA5, version 1, a type
nibble, a 16-bit word, the body, a CRC-32 of everything before it) with type numbers that
neither the map link (1-9) nor the fix packets (12-14) use, so one radio carries all three and
a receiver tells them apart by the type nibble. The 16-bit word names the sending agent (high
byte) and the map frame (low byte); every body starts with the sender's transmission serial
(u16), so a copy the protocol sent again differs from a copy the channel duplicated.

TILE (10): ``serial`` u16, ``owner`` u8 (whose map layer), ``tile`` u16, ``version`` u32,
``profile`` u32 (the id of the owner's tile profile, ``fsw.core.codec.tileformat``: frame,
grid and codec settings), then the tile's body in the compact tile format (it decodes alone
with that profile). Its digest (:func:`blob_digest`: 4 bytes of BLAKE2b of the body) is
computed, not sent.

DIGEST (11): ``serial`` u16, ``boot`` u8 (the low byte of the sender's boot id), ``dseq`` u8
(this digest's number), ``echo_dseq`` u8 (the peer's last digest received), ``echo_serial``
u16 (the peer's last packet received), ``flags`` u8 (bit 0: send me your holdings of my layer;
bit 1: answer with a digest now; bit 2: the ack list is cut short; bit 3: an echo is valid;
bit 4: started with no replica; bit 5: my tile profile follows; bit 6: wants follow),
``held_hash`` 6 bytes (:meth:`~fsw.comm.team.map_sync.MapSync.layer_hash` of the sender's copy of
the receiver's layer), ``n_acks`` u8 and ``n_acks`` x (``tile`` u16, ``version`` u16: the low 16
bits), with bit 6 ``n_wants`` u8 and ``n_wants`` x ``tile`` u16 (tiles of the sender's own
layer it asks to be given back), then with bit 5 the sender's tile profile (``TileProfile.to_bytes``, 51 bytes):
a DIGEST that asks for holdings carries it until the holdings name it.

HOLDINGS (15): ``serial`` u16, ``set_id`` u16, ``page`` u8, ``n_pages`` u8, ``profile`` u32
(the id of the receiver's tile profile the sender holds, 0: none), then entries (``tile`` u16,
``version`` u32, ``digest`` u32) of the sender's copy of the receiver's layer, for the tiles
``page * per`` up to ``(page + 1) * per`` (``per`` entries fit the MTU).

:func:`decode` raises :class:`~fsw.comm.link_packets.PacketError` with a one-line reason.
"""

from __future__ import annotations

import hashlib
import struct
import zlib
from dataclasses import dataclass

from fsw.comm.link_packets import MAGIC, VERSION, PacketError
from fsw.core.codec.mapformat import MapCodecError
from fsw.core.codec.tileformat import PROFILE_BYTES, TileProfile, profile_from_bytes

TILE, DIGEST, HOLDINGS = 10, 11, 15
SYNC_TYPES = frozenset({TILE, DIGEST, HOLDINGS})
FRAME_BYTES = 8  # header 4 + CRC 4
_TILE = struct.Struct("<HBHII")
_DIGEST = struct.Struct("<HBBBHB6sB")
HASH_BYTES = 6
_ACK = struct.Struct("<HH")
_HOLD = struct.Struct("<HHBBI")
_ENTRY = struct.Struct("<HII")
TILE_OVERHEAD = FRAME_BYTES + _TILE.size
DIGEST_BASE = FRAME_BYTES + _DIGEST.size
ACK_BYTES, WANT_BYTES, ENTRY_BYTES = _ACK.size, 2, _ENTRY.size
HOLDINGS_BASE = FRAME_BYTES + _HOLD.size

WANT_HOLDINGS, ANSWER_NOW, ACKS_CUT, ECHO_VALID, FRESH, HAS_PROFILE, HAS_WANTS = 1, 2, 4, 8, 16, 32, 64


@dataclass(frozen=True)
class Tile:
    agent: int  # the sender
    frame: int
    serial: int
    owner: int  # whose layer the tile belongs to
    tile: int
    version: int
    profile: int  # the id of the owner's tile profile
    blob: bytes

    @property
    def digest(self) -> int:
        return blob_digest(self.blob)


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
    held_hash: bytes
    acks: tuple[tuple[int, int], ...]
    wants: tuple[int, ...]
    profile: TileProfile | None = None  # the sender's, with flag HAS_PROFILE


@dataclass(frozen=True)
class Holdings:
    agent: int
    frame: int
    serial: int
    set_id: int
    page: int
    n_pages: int
    profile: int  # the id of the receiver's tile profile the sender holds (0: none)
    entries: tuple[tuple[int, int, int], ...]  # (tile, version, digest)


SyncPacket = Tile | Digest | Holdings


def blob_digest(blob: bytes) -> int:
    """A tile's content digest (what DIGESTs and HOLDINGS name a tile version's content by)."""
    return int.from_bytes(hashlib.blake2b(blob, digest_size=4).digest(), "little")


def _frame(ptype: int, agent: int, frame: int, body: bytes) -> bytes:
    msg = struct.pack("<BBBB", MAGIC, (VERSION << 4) | ptype, frame & 0xFF, agent & 0xFF) + body
    return msg + struct.pack("<I", zlib.crc32(msg))


def encode(p: SyncPacket) -> bytes:
    if isinstance(p, Tile):
        return _frame(TILE, p.agent, p.frame, _TILE.pack(p.serial & 0xFFFF, p.owner, p.tile, p.version,
                                                          p.profile) + p.blob)
    if isinstance(p, Digest):
        flags = ((p.flags & ~(HAS_PROFILE | HAS_WANTS)) | (HAS_PROFILE if p.profile is not None else 0)
                 | (HAS_WANTS if p.wants else 0))
        head = _DIGEST.pack(p.serial & 0xFFFF, p.boot & 0xFF, p.dseq & 0xFF, p.echo_dseq & 0xFF,
                            p.echo_serial & 0xFFFF, flags, p.held_hash, len(p.acks))
        acks = b"".join(_ACK.pack(t, v & 0xFFFF) for t, v in p.acks)
        wants = struct.pack(f"<B{len(p.wants)}H", len(p.wants), *p.wants) if p.wants else b""
        prof = p.profile.to_bytes() if p.profile is not None else b""
        return _frame(DIGEST, p.agent, p.frame, head + acks + wants + prof)
    body = _HOLD.pack(p.serial & 0xFFFF, p.set_id & 0xFFFF, p.page, p.n_pages, p.profile)
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
            serial, owner, tile, version, profile = _TILE.unpack_from(body)
            blob = body[_TILE.size:]
            if not blob:
                raise PacketError("TILE without a body")
            return Tile(agent, frame, serial, owner, tile, version, profile, blob)
        if ptype == DIGEST:
            return _digest(agent, frame, body)
        if ptype == HOLDINGS:
            serial, set_id, page, n_pages, profile = _HOLD.unpack_from(body)
            rest = body[_HOLD.size:]
            if len(rest) % _ENTRY.size or page >= n_pages:
                raise PacketError("HOLDINGS page is malformed")
            entries = tuple(_ENTRY.unpack_from(rest, i) for i in range(0, len(rest), _ENTRY.size))
            return Holdings(agent, frame, serial, set_id, page, n_pages, profile, entries)
    except struct.error:
        raise PacketError(f"sync packet type {ptype} with a {len(body)}-byte body is malformed") from None
    raise PacketError(f"type {ptype} is not a sync packet")


def _digest(agent: int, frame: int, body: bytes) -> Digest:
    serial, boot, dseq, echo_dseq, echo_serial, flags, held_hash, n_acks = _DIGEST.unpack_from(body)
    off = _DIGEST.size
    acks = tuple(_ACK.unpack_from(body, off + i * _ACK.size) for i in range(n_acks))
    off += n_acks * _ACK.size
    wants: tuple[int, ...] = ()
    if flags & HAS_WANTS:
        (n_wants,) = struct.unpack_from("<B", body, off)
        wants = struct.unpack_from(f"<{n_wants}H", body, off + 1)
        off += 1 + 2 * n_wants
    tail = PROFILE_BYTES if flags & HAS_PROFILE else 0
    if off + tail != len(body) or flags > 127 or (flags & HAS_WANTS and not wants):
        raise PacketError("DIGEST fields are inconsistent")
    profile = None
    if tail:
        try:
            profile = profile_from_bytes(body[off:])
        except MapCodecError as exc:
            raise PacketError(f"DIGEST: {exc}") from None
    return Digest(agent, frame, serial, boot, dseq, echo_dseq, echo_serial, flags, held_hash, acks, tuple(wants),
                  profile)
