"""Packets of the two-way map sync (docs/sync.md; the protocol: ``fsw.comm.team.map_sync``).

They share the map link's framing (``fsw.comm.link_packets``: magic 0xA5, a version nibble, a
type nibble, a 16-bit word, the body, a CRC-32 of everything before it) with type numbers that
neither the map link (1-9) nor the fix packets (12-14) use, so one radio carries all three and
a receiver tells them apart by the type nibble. Their version is :data:`SYNC_VERSION` (2: a
TILE carries several tiles); a sync packet of another version is refused. The 16-bit word
names the sending agent (high byte) and the map frame (low byte); every body starts with the
sender's transmission serial (u16), so a copy the protocol sent again differs from a copy the
channel duplicated.

TILE (10): ``serial`` u16, ``owner`` u8 (whose map layer), ``profile`` u32 (the id of the
owner's tile profile, ``fsw.core.codec.tileformat``: frame, grid and codec settings), then one
or more tiles, each ``tile`` u16, ``version`` (varint), the body's length (varint) and the
body in the compact tile format (it decodes alone with that profile). The tiles of one packet
share its header and its serial (one acknowledgement covers them all). A tile's digest
(:func:`blob_digest`: 4 bytes of BLAKE2b of the body) is computed, not sent.

DIGEST (11): ``serial`` u16, ``boot`` u8 (the low byte of the sender's boot id),
``echo_serial`` u16 (the peer's last packet received), ``ack_bits`` u32 (bit ``i``: the peer's
packet ``echo_serial - 1 - i`` was received too; with ``echo_serial`` these acknowledge the
tiles those packets carried), ``flags`` u8 (bit 0: send me your holdings of my layer; bit 1:
answer with a digest now; bit 2: a hash follows; bit 3: the echo is valid; bit 4: started with
no replica; bit 5: my tile profile follows; bit 6: wants follow; bit 7: I hold your tile
profile), with bit 2 ``held_hash`` 6
bytes (:meth:`~fsw.comm.team.map_sync.MapSync.layer_hash` of the sender's copy of the
receiver's layer), with bit 6 ``n_wants`` u8 and ``n_wants`` x ``tile`` u16 (tiles of the
sender's own layer it asks to be given back), then with bit 5 the sender's tile profile
(``TileProfile.to_bytes``, 51 bytes): a DIGEST that asks for holdings carries it until the
peer's DIGESTs (bit 7) or holdings name it.

HOLDINGS (15): ``serial`` u16, ``set_id`` u16, ``page`` u8, ``n_pages`` u8, ``profile`` u32
(the id of the receiver's tile profile the sender holds, 0: none), then entries (``tile``: a
varint, the step from the last entry's tile, the first from the page's first tile;
``version``: a varint; ``digest`` u32) of the sender's copy of the receiver's layer, for the
tiles ``page * per`` up to ``(page + 1) * per`` (``per`` entries of the largest size fit the MTU).

:func:`decode` raises :class:`~fsw.comm.link_packets.PacketError` with a one-line reason.
"""

from __future__ import annotations

import hashlib
import struct
import zlib
from dataclasses import dataclass

from fsw.comm.link_packets import MAGIC, PacketError
from fsw.core.codec.mapformat import MapCodecError
from fsw.core.codec.tileformat import PROFILE_BYTES, TileProfile, get_varint, profile_from_bytes, put_varint

SYNC_VERSION = 2  # 2: a TILE carries several tiles
TILE, DIGEST, HOLDINGS = 10, 11, 15
SYNC_TYPES = frozenset({TILE, DIGEST, HOLDINGS})
FRAME_BYTES = 8  # header 4 + CRC 4
_TILE = struct.Struct("<HBI")
_DIGEST = struct.Struct("<HBHIB")
HASH_BYTES = 6
ACK_WINDOW = 32  # packets acknowledged by ack_bits before the echo
_HOLD = struct.Struct("<HHBBI")
TILE_BASE = FRAME_BYTES + _TILE.size  # a TILE's bytes besides its tiles
# The minimal deltas count each published tile version as its body plus this: a packet of its
# own with fixed-width fields (frame 8, serial 2, owner 1, tile 2, version u32, profile id u32;
# docs/sync.md, "Figures"). A TILE of one tile is about as large; tiles sharing a TILE, less.
MINIMAL_TILE_OVERHEAD = 21
DIGEST_BASE = FRAME_BYTES + _DIGEST.size
WANT_BYTES, ENTRY_BYTES = 2, 3 + 5 + 4  # a HOLDINGS entry at most: tile step and version varints, digest
HOLDINGS_BASE = FRAME_BYTES + _HOLD.size

WANT_HOLDINGS, ANSWER_NOW, HAS_HASH, ECHO_VALID, FRESH, HAS_PROFILE, HAS_WANTS, KNOWS_PROFILE = (
    1, 2, 4, 8, 16, 32, 64, 128)


@dataclass(frozen=True)
class TileEntry:
    """One tile of a TILE packet: its number, version and compact body."""

    tile: int
    version: int
    blob: bytes

    @property
    def digest(self) -> int:
        return blob_digest(self.blob)

    @property
    def size(self) -> int:
        """Its bytes in a TILE packet."""
        return 2 + len(put_varint(self.version)) + len(put_varint(len(self.blob))) + len(self.blob)


@dataclass(frozen=True)
class Tile:
    agent: int  # the sender
    frame: int
    serial: int
    owner: int  # whose layer the tiles belong to
    profile: int  # the id of the owner's tile profile
    tiles: tuple[TileEntry, ...]


@dataclass(frozen=True)
class Digest:
    agent: int
    frame: int
    serial: int
    boot: int
    echo_serial: int
    ack_bits: int
    flags: int
    held_hash: bytes | None  # with flag HAS_HASH
    wants: tuple[int, ...] = ()
    profile: TileProfile | None = None  # the sender's, with flag HAS_PROFILE

    def acked(self) -> list[int]:
        """The serials of the peer's packets this DIGEST acknowledges (none without an echo)."""
        if not self.flags & ECHO_VALID:
            return []
        return [self.echo_serial] + [(self.echo_serial - 1 - i) & 0xFFFF for i in range(ACK_WINDOW)
                                     if self.ack_bits >> i & 1]


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
    msg = struct.pack("<BBBB", MAGIC, (SYNC_VERSION << 4) | ptype, frame & 0xFF, agent & 0xFF) + body
    return msg + struct.pack("<I", zlib.crc32(msg))


def encode(p: SyncPacket) -> bytes:
    if isinstance(p, Tile):
        if not p.tiles or any(not e.blob for e in p.tiles):
            raise ValueError("a TILE carries one or more tiles, each with a body")
        body = bytearray(_TILE.pack(p.serial & 0xFFFF, p.owner, p.profile))
        for e in p.tiles:
            body += struct.pack("<H", e.tile) + put_varint(e.version) + put_varint(len(e.blob)) + e.blob
        return _frame(TILE, p.agent, p.frame, bytes(body))
    if isinstance(p, Digest):
        if p.held_hash is not None and len(p.held_hash) != HASH_BYTES:
            raise ValueError(f"a DIGEST's hash is {HASH_BYTES} bytes")
        flags = ((p.flags & ~(HAS_PROFILE | HAS_WANTS | HAS_HASH)) | (HAS_PROFILE if p.profile is not None else 0)
                 | (HAS_WANTS if p.wants else 0) | (HAS_HASH if p.held_hash is not None else 0))
        head = _DIGEST.pack(p.serial & 0xFFFF, p.boot & 0xFF, p.echo_serial & 0xFFFF, p.ack_bits & 0xFFFFFFFF, flags)
        held = p.held_hash or b""
        wants = struct.pack(f"<B{len(p.wants)}H", len(p.wants), *p.wants) if p.wants else b""
        prof = p.profile.to_bytes() if p.profile is not None else b""
        return _frame(DIGEST, p.agent, p.frame, head + held + wants + prof)
    body = bytearray(_HOLD.pack(p.serial & 0xFFFF, p.set_id & 0xFFFF, p.page, p.n_pages, p.profile))
    prev = -1
    for t, v, dig in p.entries:
        if t <= prev:
            raise ValueError("HOLDINGS entries go by increasing tile")
        body += put_varint(t - prev - 1) + put_varint(v) + struct.pack("<I", dig)
        prev = t
    return _frame(HOLDINGS, p.agent, p.frame, bytes(body))


def is_sync_packet(datagram: bytes) -> bool:
    """Whether a datagram's header names a sync type (the routing test; integrity is decode's)."""
    return len(datagram) >= 2 and datagram[0] == MAGIC and (datagram[1] & 0xF) in SYNC_TYPES


def decode(datagram: bytes) -> SyncPacket:
    d = bytes(datagram)
    if len(d) < FRAME_BYTES + 2:
        raise PacketError(f"sync packet of {len(d)} bytes is too short")
    if d[0] != MAGIC or d[1] >> 4 != SYNC_VERSION:
        raise PacketError(f"not a version-{SYNC_VERSION} sync packet")
    if struct.unpack("<I", d[-4:])[0] != zlib.crc32(d[:-4]):
        raise PacketError("sync packet CRC mismatch")
    ptype, frame, agent, body = d[1] & 0xF, d[2], d[3], d[4:-4]
    try:
        if ptype == TILE:
            serial, owner, profile = _TILE.unpack_from(body)
            return Tile(agent, frame, serial, owner, profile, _tile_entries(body, _TILE.size))
        if ptype == DIGEST:
            return _digest(agent, frame, body)
        if ptype == HOLDINGS:
            serial, set_id, page, n_pages, profile = _HOLD.unpack_from(body)
            if page >= n_pages:
                raise PacketError("HOLDINGS page is malformed")
            return Holdings(agent, frame, serial, set_id, page, n_pages, profile, _entries(body, _HOLD.size))
    except struct.error:
        raise PacketError(f"sync packet type {ptype} with a {len(body)}-byte body is malformed") from None
    raise PacketError(f"type {ptype} is not a sync packet")


def _tile_entries(body: bytes, off: int) -> tuple[TileEntry, ...]:
    out: list[TileEntry] = []
    try:
        while off < len(body) or not out:
            (tile,) = struct.unpack_from("<H", body, off)
            version, off = get_varint(body, off + 2)
            n, off = get_varint(body, off)
            if n == 0 or off + n > len(body) or version > 0xFFFFFFFF:
                raise PacketError("TILE entry is malformed")
            out.append(TileEntry(tile, version, body[off:off + n]))
            off += n
    except MapCodecError:
        raise PacketError("TILE entry is malformed") from None
    return tuple(out)


def _entries(body: bytes, off: int) -> tuple[tuple[int, int, int], ...]:
    out = []
    prev = -1
    try:
        while off < len(body):
            step, off = get_varint(body, off)
            version, off = get_varint(body, off)
            (dig,) = struct.unpack_from("<I", body, off)
            off += 4
            prev += step + 1
            if prev > 0xFFFF or version > 0xFFFFFFFF:
                raise PacketError("HOLDINGS entry out of range")
            out.append((prev, version, dig))
    except MapCodecError:
        raise PacketError("HOLDINGS page is malformed") from None
    return tuple(out)


def _digest(agent: int, frame: int, body: bytes) -> Digest:
    serial, boot, echo_serial, ack_bits, flags = _DIGEST.unpack_from(body)
    off = _DIGEST.size
    held: bytes | None = None
    if flags & HAS_HASH:
        held = body[off:off + HASH_BYTES]
        off += HASH_BYTES
    wants: tuple[int, ...] = ()
    if flags & HAS_WANTS:
        (n_wants,) = struct.unpack_from("<B", body, off)
        wants = struct.unpack_from(f"<{n_wants}H", body, off + 1)
        off += 1 + 2 * n_wants
    tail = PROFILE_BYTES if flags & HAS_PROFILE else 0
    if off + tail != len(body) or (flags & HAS_WANTS and not wants):
        raise PacketError("DIGEST fields are inconsistent")
    profile = None
    if tail:
        try:
            profile = profile_from_bytes(body[off:])
        except MapCodecError as exc:
            raise PacketError(f"DIGEST: {exc}") from None
    return Digest(agent, frame, serial, boot, echo_serial, ack_bits, flags, held, tuple(wants), profile)
