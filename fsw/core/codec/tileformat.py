"""The compact tile format: one map tile's codec streams without the container header
(docs/sync.md, "Tiles"; the container: ``fsw.core.codec.mapformat``).

A map-codec container repeats, for every map, what the receiver of many small tiles of one
map already knows: the grid, the cell size, the wheel and error bound, the lattice step and
the codec's modes (108 bytes, 112 with its CRC). A tile of the map sync carries only what is
its own; the rest is a :class:`TileProfile`, agreed once per session and named in every tile
packet by its 4-byte :attr:`TileProfile.pid`, so a tile decodes alone given its profile and a
tile of another profile (another frame, grid or codec) is never decoded with the wrong one.

Profile (little-endian, :data:`PROFILE_BYTES` bytes)::

    off  size  field
    0    1     profile format version (1)
    1    1     map frame id
    2    4     grid rows ny (u32)          6   4  grid columns nx (u32)
    10   4     cell_m (f32)                14  4  grid origin x0, m (f32)
    18   4     grid origin y0, m (f32)     22  2  tile side, cells (u16)
    24   4     wheel_diameter_m (f32)      28  4  error_bound_m (f32)
    32   8     quant_step_m (f64: the lattice step)
    40   1     flags: bit 0 hazard-preserving reduction
    41   1     split rule (0 entropy, 1 bound)      42  1  leaf value mode (0 predictive, 1 mean)
    43   4     hazard threshold, m (f32)            47  4  relief disc diameter, m (f32)

Tile body (what a tile packet carries after its profile id)::

    0    1     flags: bit 0 the tile has unknown cells, bit 1 the payload is one zstandard frame
    1    v     the height offset in lattice steps (zigzag varint): z_offset = k * quant_step
    .    v     raw length of the tree split flags (varint)
    .    v     raw length of the known-leaf flags (varint; only with bit 0)
    .    v     raw length of the residual bytes (varint)
    .    P     payload: the four streams back to back (the residual escapes are the rest),
               raw, or (bit 1) one magic-less zstandard frame of them, whichever is shorter

A tile has no checksum of its own: the packet that carries it has its CRC-32. Every failure
is a :class:`~fsw.core.codec.mapformat.MapCodecError` with a one-line reason.
"""

from __future__ import annotations

import hashlib
import math
import struct
from dataclasses import dataclass

import zstandard

from fsw.core.codec.mapformat import MapCodecError, compressor

PROFILE_VERSION = 1
_PROFILE = struct.Struct("<BBIIfffHffdBBBff")
PROFILE_BYTES = _PROFILE.size  # 51
_RULES = ("entropy", "bound")
_MODES = ("predictive", "mean")
HAS_UNKNOWN, COMPRESSED = 1, 2


@dataclass(frozen=True)
class TileProfile:
    """What every tile of one agent's layer shares: the frame and grid the tiles are cut from
    and the codec settings they were reduced with (module docstring)."""

    frame: int
    ny: int
    nx: int
    cell_m: float
    x0: float
    y0: float
    tile_cells: int
    wheel_diameter_m: float
    error_bound_m: float
    quant_step_m: float
    hazard: bool
    split_rule: str
    leaf_value: str
    hazard_threshold_m: float
    relief_disc_m: float

    def to_bytes(self) -> bytes:
        return _PROFILE.pack(PROFILE_VERSION, self.frame & 0xFF, self.ny, self.nx, self.cell_m, self.x0, self.y0,
                             self.tile_cells, self.wheel_diameter_m, self.error_bound_m, self.quant_step_m,
                             int(self.hazard), _RULES.index(self.split_rule), _MODES.index(self.leaf_value),
                             self.hazard_threshold_m, self.relief_disc_m)

    @property
    def pid(self) -> int:
        """The profile's 4-byte id: BLAKE2b of its bytes (what every tile packet names)."""
        return int.from_bytes(hashlib.blake2b(self.to_bytes(), digest_size=4).digest(), "little")

    def same_grid(self, other: TileProfile) -> bool:
        """Whether both profiles cut their tiles from the same frame and grid."""
        return (self.frame, self.ny, self.nx, self.cell_m, self.x0, self.y0, self.tile_cells) == (
            other.frame, other.ny, other.nx, other.cell_m, other.x0, other.y0, other.tile_cells)

    def rounded(self) -> TileProfile:
        """The profile as its bytes hold it (float32 fields rounded): what a receiver decodes."""
        return profile_from_bytes(self.to_bytes())


def profile_from_bytes(data: bytes) -> TileProfile:
    """A profile from its bytes; ``MapCodecError`` (one line) when they are not a valid one."""
    if len(data) != PROFILE_BYTES:
        raise MapCodecError(f"a tile profile is {PROFILE_BYTES} bytes, not {len(data)}")
    (ver, frame, ny, nx, cell, x0, y0, tc, wheel, bound, q, flags, rule, mode, thr, disc) = _PROFILE.unpack(data)
    if ver != PROFILE_VERSION:
        raise MapCodecError(f"tile profile version {ver} (this decoder reads {PROFILE_VERSION})")
    if flags > 1 or rule >= len(_RULES) or mode >= len(_MODES):
        raise MapCodecError("unknown flag or mode values in the tile profile")
    if not (ny >= 1 and nx >= 1 and 1 <= tc <= 4096):
        raise MapCodecError(f"tile profile grid {ny}x{nx} with tiles of {tc} cells is impossible")
    vals = (cell, x0, y0, wheel, bound, q, thr, disc)
    if not all(math.isfinite(v) for v in vals) or not (cell > 0 and bound > 0 and q > 0):
        raise MapCodecError("invalid cell size, error bound or lattice step in the tile profile")
    return TileProfile(frame, ny, nx, cell, x0, y0, tc, wheel, bound, q, bool(flags), _RULES[rule], _MODES[mode],
                       thr, disc)


def put_varint(n: int) -> bytes:
    """``n`` (>= 0) as a LEB128 varint."""
    out = bytearray()
    while True:
        b = n & 0x7F
        n >>= 7
        if n:
            out.append(b | 0x80)
        else:
            out.append(b)
            return bytes(out)


def get_varint(data: bytes, pos: int) -> tuple[int, int]:
    """(the varint at ``pos``, the position after it); ``MapCodecError`` if truncated or over-long."""
    n = shift = 0
    while True:
        if pos >= len(data) or shift > 35:
            raise MapCodecError("tile body is truncated or has an over-long number")
        b = data[pos]
        n |= (b & 0x7F) << shift
        pos += 1
        shift += 7
        if not b & 0x80:
            return n, pos


def pack_tile(has_unknown: bool, offset_steps: int, streams: list[bytes], level: int) -> bytes:
    """A tile body from its four raw streams (split, known, residuals, escapes)."""
    zz = (offset_steps << 1) ^ (offset_steps >> 63)
    lens = [len(streams[0]), *([len(streams[1])] if has_unknown else []), len(streams[2])]
    raw = b"".join(streams)
    coded = compressor(level).compress(raw) if raw else b""
    packed = len(coded) < len(raw)
    flags = (HAS_UNKNOWN if has_unknown else 0) | (COMPRESSED if packed else 0)
    return bytes([flags]) + put_varint(zz) + b"".join(put_varint(n) for n in lens) + (coded if packed else raw)


def unpack_tile(data: bytes, max_cells: int) -> tuple[bool, int, list[bytes]]:
    """(has unknown cells, offset in lattice steps, the four raw streams) of a tile body of at
    most ``max_cells`` cells; ``MapCodecError`` (one line) when it is not a valid one."""
    data = bytes(data)
    if not data:
        raise MapCodecError("empty tile body")
    flags = data[0]
    if flags > HAS_UNKNOWN | COMPRESSED:
        raise MapCodecError(f"unknown tile flags {flags:#x}")
    zz, pos = get_varint(data, 1)
    off = (zz >> 1) ^ -(zz & 1)
    has_unknown = bool(flags & HAS_UNKNOWN)
    lens = []
    for _ in range(3 if has_unknown else 2):
        n, pos = get_varint(data, pos)
        lens.append(n)
    split_n, small_n = lens[0], lens[-1]
    known_n = lens[1] if has_unknown else 0
    limit = 6 * max_cells + 64  # split bits, known bits, a byte and an escape per cell
    if split_n > max_cells // 4 + 8 or known_n > max_cells // 8 + 8 or small_n > max_cells + 8:
        raise MapCodecError("stream lengths in the tile body are impossible for its size")
    payload = data[pos:]
    if flags & COMPRESSED:
        try:
            dctx = zstandard.ZstdDecompressor(format=zstandard.FORMAT_ZSTD1_MAGICLESS)
            payload = dctx.decompress(payload, max_output_size=limit)
        except (zstandard.ZstdError, MemoryError) as exc:  # also a frame larger than the tile allows
            raise MapCodecError(f"tile payload does not decompress ({type(exc).__name__}: {exc})") from None
    fixed = split_n + known_n + small_n
    if len(payload) < fixed or (len(payload) - fixed) % 4:
        raise MapCodecError(f"tile payload of {len(payload)} bytes does not fit its stream lengths")
    a, b = split_n, split_n + known_n
    return has_unknown, off, [payload[:a], payload[a:b], payload[b:fixed], payload[fixed:]]
