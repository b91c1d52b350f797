"""The map container: a versioned, checksummed byte layout for the codec (docs/algorithm.md §6.5).

Layout (little-endian; docs/quadtree.md has the same table)::

    off  size  field
    0    4     magic b"SQMC"
    4    1     version (2; version 1 containers, without the hazard fields, still decode)
    5    1     flags: bit 0 = map has unknown cells, bit 1 = hazard-preserving reduction,
               bit 2 = its relief hazards read across the ground (relief x cos(slope))
    6    1     split rule: 0 entropy, 1 bound
    7    1     leaf value mode: 0 predictive, 1 mean
    8    4     ny (u32)             12  4  nx (u32)
    16   4     cell_m (f32)         20  4  wheel_diameter_m (f32)
    24   4     error_bound_m (f32)  28  8  quant_step_m (f64)
    36   8     z_offset_m (f64)     44  4  n_leaves (u32)
    48   4     hazard threshold, m (f32: relief or step that makes a cell critical)
    52   4     relief disc diameter, m (f32)     56  4  step disc diameter, m (f32)
    60   4     support rise, m (f32)             64  4  step slack, m (f32)
    68   4     relief loss bound on relief hazards, m (f32)
    72   4     relief loss bound on any cell, m (f32)
    76   16    raw length of each of the 4 streams (u32 each): tree split flags,
               known-leaf flags, residual bytes, residual escapes (u32 LE each)
    92   16    coded length of each stream (u32 each); the payload length P is their sum
    108  P     payload: per non-empty stream, one magic-less zstandard frame
    108+P 4    CRC-32 (zlib) of bytes 0 .. 108+P

Version 1 had no hazard fields (bytes 48-75): its stream lengths start at 48 and the
payload at 80; it decodes with the hazard fields NaN.

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
VERSION = 2
_HEAD_V1 = struct.Struct("<4sBBBBIIfffddI4I4I")
_HEAD = struct.Struct("<4sBBBBIIfffddI7f4I4I")
HEADER_BYTES = _HEAD.size  # 108
_NAN7 = (float("nan"),) * 7
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
    hazard: bool = False  # the hazard-preserving reduction (fsw.core.codec.hazard) was used
    hazard_threshold_m: float = float("nan")
    relief_disc_m: float = float("nan")
    step_disc_m: float = float("nan")
    support_rise_m: float = float("nan")
    step_slack_m: float = float("nan")
    relief_loss_hazard_m: float = float("nan")  # bound on cells with relief >= the threshold
    # the threshold is across the ground: relief x cos(slope) over the relief disc
    # (fsw.core.codec.relief_hold.across_ground), as the receiver's planner reads a rock
    hazard_across_ground: bool = False
    relief_loss_any_m: float = float("nan")  # bound on every known cell
    version: int = VERSION

    def hazard_fields(self) -> tuple[float, ...]:
        return (self.hazard_threshold_m, self.relief_disc_m, self.step_disc_m, self.support_rise_m,
                self.step_slack_m, self.relief_loss_hazard_m, self.relief_loss_any_m)


def compressor(level: int) -> zstandard.ZstdCompressor:
    """The zstandard settings of the payload: no magic, checksum, size or dictionary id."""
    return zstandard.ZstdCompressor(compression_params=zstandard.ZstdCompressionParameters.from_level(
        level, format=zstandard.FORMAT_ZSTD1_MAGICLESS, write_checksum=0, write_content_size=0,
        write_dict_id=0))


def pack(header: Header, streams: list[bytes], cctx: zstandard.ZstdCompressor) -> bytes:
    """Container bytes for ``header`` and the four raw streams."""
    coded = [cctx.compress(s) if s else b"" for s in streams]
    flags = (1 if header.has_unknown else 0) | (2 if header.hazard else 0) | (4 if header.hazard_across_ground else 0)
    head = _HEAD.pack(
        MAGIC, VERSION, flags, _RULES.index(header.split_rule),
        _MODES.index(header.leaf_value), header.ny, header.nx, header.cell_m,
        header.wheel_diameter_m, header.error_bound_m, header.quant_step_m, header.z_offset_m,
        header.n_leaves, *header.hazard_fields(), *(len(s) for s in streams), *(len(c) for c in coded))
    body = head + b"".join(coded)
    return body + struct.pack("<I", zlib.crc32(body))


def unpack(data: bytes, *, max_cells: int) -> tuple[Header, list[bytes]]:
    """Validate a container and return its header and the four raw streams."""
    data = bytes(data)
    if data[:4] and not MAGIC.startswith(data[:4]):
        raise MapCodecError("not a map container (bad magic)")
    if len(data) < 5:
        raise MapCodecError(f"truncated: {len(data)} bytes, the header alone needs {HEADER_BYTES + 4}")
    version = data[4]
    if version not in (1, VERSION):
        raise MapCodecError(f"unsupported container version {version} (this decoder reads 1 and {VERSION})")
    st = _HEAD if version == VERSION else _HEAD_V1
    if len(data) < st.size + 4:
        raise MapCodecError(f"truncated: {len(data)} bytes, the header alone needs {st.size + 4}")
    fields = st.unpack_from(data)
    (magic, version, flags, rule, mode, ny, nx, cell_m, wheel_m, bound_m, q, off, n_leaves) = fields[:13]
    hazard = tuple(fields[13:20]) if version == VERSION else _NAN7
    lens = fields[-8:]
    lengths, coded_lengths = tuple(lens[:4]), tuple(lens[4:])
    plen = sum(coded_lengths)
    want = st.size + plen + 4
    if len(data) < want:
        raise MapCodecError(f"truncated: {len(data)} bytes, the header announces {want}")
    if len(data) > want:
        raise MapCodecError(f"{len(data) - want} unexpected bytes after the end of the container")
    (crc,) = struct.unpack_from("<I", data, want - 4)
    if zlib.crc32(data[: want - 4]) != crc:
        raise MapCodecError("CRC-32 mismatch: the container is corrupted")
    if flags > (7 if version == VERSION else 1) or rule >= len(_RULES) or mode >= len(_MODES):
        raise MapCodecError("unknown flag or mode values in the header")
    if flags & 4 and not flags & 2:
        raise MapCodecError("hazards read across the ground without the hazard rule in the header")
    if ny < 1 or nx < 1 or ny * nx > max_cells:
        raise MapCodecError(f"map size {ny}x{nx} outside 1..{max_cells} cells")
    if not (q > 0 and math.isfinite(q) and math.isfinite(off) and bound_m > 0):
        raise MapCodecError("invalid quantisation step, offset or error bound in the header")
    if flags & 2 and not all(math.isfinite(v) and v >= 0 for v in hazard):
        raise MapCodecError("invalid hazard fields in the header")
    cells = ny * nx
    limits = (cells // 4 + 8, cells // 8 + 8, cells + 8, 4 * cells + 8)
    if any(n > lim for n, lim in zip(lengths, limits, strict=True)) or n_leaves > cells:
        raise MapCodecError("stream lengths in the header are impossible for this map size")
    dctx = zstandard.ZstdDecompressor(format=zstandard.FORMAT_ZSTD1_MAGICLESS)
    streams, pos = [], st.size
    for k, (n, nc) in enumerate(zip(lengths, coded_lengths, strict=True)):
        if (n == 0) != (nc == 0):
            raise MapCodecError(f"stream {k}: coded and raw lengths disagree")
        raw = b""
        if n:
            try:
                raw = dctx.decompress(data[pos:pos + nc], max_output_size=n)
            except (zstandard.ZstdError, MemoryError) as exc:  # a forged frame may claim a huge window
                raise MapCodecError(f"stream {k} does not decompress ({type(exc).__name__}: {exc})") from None
        if len(raw) != n:
            raise MapCodecError(f"stream {k} holds {len(raw)} bytes, the header announces {n}")
        streams.append(raw)
        pos += nc
    header = Header(ny=ny, nx=nx, cell_m=cell_m, wheel_diameter_m=wheel_m, error_bound_m=bound_m,
                    quant_step_m=q, z_offset_m=off, n_leaves=n_leaves, has_unknown=bool(flags & 1),
                    split_rule=_RULES[rule], leaf_value=_MODES[mode], hazard=bool(flags & 2),
                    hazard_threshold_m=hazard[0], relief_disc_m=hazard[1], step_disc_m=hazard[2],
                    support_rise_m=hazard[3], step_slack_m=hazard[4], relief_loss_hazard_m=hazard[5],
                    relief_loss_any_m=hazard[6], hazard_across_ground=bool(flags & 4), version=version)
    return header, streams
