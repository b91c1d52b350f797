"""The map container: a versioned, checksummed byte layout for the codec (docs/algorithm.md §6.5).

Layout (little-endian; docs/quadtree.md has the same table)::

    off  size  field
    0    4     magic b"SQMC"
    4    1     version (1)
    5    1     flags: bit 0 = map has unknown cells
    6    1     split rule: 0 entropy, 1 bound
    7    1     leaf value mode: 0 predictive, 1 mean
    8    4     ny (u32)             12  4  nx (u32)
    16   4     cell_m (f32)         20  4  wheel_diameter_m (f32)
    24   4     error_bound_m (f32)  28  8  quant_step_m (f64)
    36   8     z_offset_m (f64)     44  4  n_leaves (u32)
    48   16    raw length of each of the 4 streams (u32 each): tree split flags,
               known-leaf flags, residual bytes, residual escapes (u32 LE each)
    64   16    coded length of each stream (u32 each); the payload length P is their sum
    80   P     payload: per non-empty stream, one magic-less zstandard frame
    80+P 4     CRC-32 (zlib) of bytes 0 .. 80+P

Every check a decoder needs is here, and each failure is a :class:`MapCodecError` with a
one-line reason, so a CLI prints it and exits 2 and the Cliff-bot reports it.
"""

from __future__ import annotations

import math
import struct
import zlib
from dataclasses import dataclass

import zstandard

MAGIC = b"SQMC"
VERSION = 1
_HEAD = struct.Struct("<4sBBBBIIfffddI4I4I")
HEADER_BYTES = _HEAD.size  # 80
_RULES = ("entropy", "bound")
_MODES = ("predictive", "mean")


class MapCodecError(ValueError):
    """Bad, truncated or corrupted map container."""


@dataclass(frozen=True)
class Header:
    ny: int
    nx: int
    cell_m: float
    wheel_diameter_m: float
    error_bound_m: float
    quant_step_m: float
    z_offset_m: float
    n_leaves: int
    has_unknown: bool
    split_rule: str
    leaf_value: str


def compressor(level: int) -> zstandard.ZstdCompressor:
    """The zstandard settings of the payload: no magic, checksum, size or dictionary id."""
    return zstandard.ZstdCompressor(compression_params=zstandard.ZstdCompressionParameters.from_level(
        level, format=zstandard.FORMAT_ZSTD1_MAGICLESS, write_checksum=0, write_content_size=0,
        write_dict_id=0))


def pack(header: Header, streams: list[bytes], cctx: zstandard.ZstdCompressor) -> bytes:
    """Container bytes for ``header`` and the four raw streams."""
    coded = [cctx.compress(s) if s else b"" for s in streams]
    head = _HEAD.pack(
        MAGIC, VERSION, 1 if header.has_unknown else 0, _RULES.index(header.split_rule),
        _MODES.index(header.leaf_value), header.ny, header.nx, header.cell_m,
        header.wheel_diameter_m, header.error_bound_m, header.quant_step_m, header.z_offset_m,
        header.n_leaves, *(len(s) for s in streams), *(len(c) for c in coded))
    body = head + b"".join(coded)
    return body + struct.pack("<I", zlib.crc32(body))


def unpack(data: bytes, *, max_cells: int) -> tuple[Header, list[bytes]]:
    """Validate a container and return its header and the four raw streams."""
    data = bytes(data)
    if len(data) < HEADER_BYTES + 4:
        if data[:4] and not MAGIC.startswith(data[:4]):
            raise MapCodecError("not a map container (bad magic)")
        raise MapCodecError(f"truncated: {len(data)} bytes, the header alone needs {HEADER_BYTES + 4}")
    (magic, version, flags, rule, mode, ny, nx, cell_m, wheel_m, bound_m, q, off, n_leaves,
     *lens) = _HEAD.unpack_from(data)
    lengths, coded_lengths = tuple(lens[:4]), tuple(lens[4:])
    plen = sum(coded_lengths)
    if magic != MAGIC:
        raise MapCodecError("not a map container (bad magic)")
    if version != VERSION:
        raise MapCodecError(f"unsupported container version {version} (this decoder reads {VERSION})")
    want = HEADER_BYTES + plen + 4
    if len(data) < want:
        raise MapCodecError(f"truncated: {len(data)} bytes, the header announces {want}")
    if len(data) > want:
        raise MapCodecError(f"{len(data) - want} unexpected bytes after the end of the container")
    (crc,) = struct.unpack_from("<I", data, want - 4)
    if zlib.crc32(data[: want - 4]) != crc:
        raise MapCodecError("CRC-32 mismatch: the container is corrupted")
    if flags > 1 or rule >= len(_RULES) or mode >= len(_MODES):
        raise MapCodecError("unknown flag or mode values in the header")
    if ny < 1 or nx < 1 or ny * nx > max_cells:
        raise MapCodecError(f"map size {ny}x{nx} outside 1..{max_cells} cells")
    if not (q > 0 and math.isfinite(q) and math.isfinite(off) and bound_m > 0):
        raise MapCodecError("invalid quantisation step, offset or error bound in the header")
    cells = ny * nx
    limits = (cells // 4 + 8, cells // 8 + 8, cells + 8, 4 * cells + 8)
    if any(n > lim for n, lim in zip(lengths, limits, strict=True)) or n_leaves > cells:
        raise MapCodecError("stream lengths in the header are impossible for this map size")
    dctx = zstandard.ZstdDecompressor(format=zstandard.FORMAT_ZSTD1_MAGICLESS)
    streams, pos = [], HEADER_BYTES
    for k, (n, nc) in enumerate(zip(lengths, coded_lengths, strict=True)):
        if (n == 0) != (nc == 0):
            raise MapCodecError(f"stream {k}: coded and raw lengths disagree")
        raw = b""
        if n:
            try:
                raw = dctx.decompress(data[pos:pos + nc], max_output_size=n)
            except zstandard.ZstdError as exc:
                raise MapCodecError(f"stream {k} does not decompress ({exc})") from None
        if len(raw) != n:
            raise MapCodecError(f"stream {k} holds {len(raw)} bytes, the header announces {n}")
        streams.append(raw)
        pos += nc
    header = Header(ny=ny, nx=nx, cell_m=cell_m, wheel_diameter_m=wheel_m, error_bound_m=bound_m,
                    quant_step_m=q, z_offset_m=off, n_leaves=n_leaves, has_unknown=bool(flags & 1),
                    split_rule=_RULES[rule], leaf_value=_MODES[mode])
    return header, streams
