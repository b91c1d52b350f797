"""Checkpoint format: the elevation map (docs/algorithm.md §1) and the mission state, checksummed.

Pure encode/decode (no I/O, as ``fsw/core`` requires); ``fsw.drivers.map_store`` writes
them atomically and loads the newest good one. Layout, all little-endian::

    b"SAFERMAP"  u16 version  u32 header_len  header (UTF-8 JSON)  body  [state]  sha256(all before)

The header holds the grid, ``n_max``, the sequence number, the mission time and, per array
(``z var n interest misses outliers var_common``), its dtype and shape; ``body_len`` is the length
of the zstandard-compressed concatenation of the arrays. Version 2 adds ``state_len``: the
length of the zstandard-compressed JSON mission state that follows the body (0: a map-only
checkpoint), so the map of step k and the mission state of step k are one snapshot under one
checksum (docs/hil.md, "Resuming a mission"). Version 1 files (map only) are still read.
Any truncation, bit flip, wrong magic or version, inconsistent header, array shape or state
raises ``CheckpointError`` with the reason; nothing half-decoded is ever returned.
"""

from __future__ import annotations

import hashlib
import json
import struct
from dataclasses import dataclass
from typing import Any

import numpy as np
import zstandard

from fsw.core.geometry import MapGrid
from fsw.core.map.elevation_map import ElevationMap, FusionConfig
from fsw.framework.params import param

MAGIC = b"SAFERMAP"
VERSION = 2
READABLE_VERSIONS = (1, 2)
_HEAD = struct.Struct("<8sHI")
_DIGEST = 32
_ARRAYS = (("z", "<f8"), ("var", "<f8"), ("n", "<i4"), ("interest", "<f8"),
           ("misses", "<i4"), ("outliers", "<i4"), ("var_common", "<f8"))
_MAX_HEADER = 1 << 16
_MAX_STATE = 64 << 20  # decompressed mission state, bytes


class CheckpointError(ValueError):
    """A checkpoint that cannot be trusted (truncated, corrupt, wrong version)."""


@dataclass(frozen=True)
class CheckpointConfig:
    """Map checkpoints (config ``[checkpoint]``)."""

    directory: str = param("out/checkpoints", doc="where checkpoints are written")
    period_s: float = param(60.0, lo=1.0, hi=86400.0, units="s", doc="periodic save interval")
    keep: int = param(3, lo=2, hi=100, doc="checkpoints kept (the newest and its fallbacks)")
    compression_level: int = param(3, lo=1, hi=19, doc="zstandard level")


@dataclass(frozen=True)
class CheckpointMeta:
    seq: int
    time_s: float
    state: dict[str, Any] | None = None  # the mission state saved with the map (None: map only)
    version: int = VERSION


def encode(
    emap: ElevationMap, seq: int, time_s: float, level: int = 3, state: dict[str, Any] | None = None
) -> bytes:
    """The map (and the mission state, a JSON-able dict, if given) as checkpoint bytes."""
    g = emap.grid
    raw = b"".join(np.ascontiguousarray(getattr(emap, name), dtype=dt).tobytes()
                   for name, dt in _ARRAYS)
    zc = zstandard.ZstdCompressor(level=level)
    body = zc.compress(raw)
    state_raw = b"" if state is None else json.dumps(state, allow_nan=True, sort_keys=True).encode()
    state_z = zc.compress(state_raw) if state is not None else b""
    header = json.dumps({
        "grid": [g.x0, g.y0, g.cell, g.nx, g.ny], "n_max": emap.n_max, "seq": int(seq),
        "time_s": float(time_s), "body_len": len(body), "raw_len": len(raw),
        "arrays": [[name, dt] for name, dt in _ARRAYS],
        "state_len": len(state_z), "state_raw_len": len(state_raw),
    }).encode()
    blob = _HEAD.pack(MAGIC, VERSION, len(header)) + header + body + state_z
    return blob + hashlib.sha256(blob).digest()


def decode(data: bytes, cfg: FusionConfig | None = None) -> tuple[ElevationMap, CheckpointMeta]:
    """Checkpoint bytes back to a map; ``CheckpointError`` if they cannot be trusted."""
    if len(data) < _HEAD.size + _DIGEST:
        raise CheckpointError(f"truncated: {len(data)} bytes is shorter than any checkpoint")
    magic, version, hlen = _HEAD.unpack_from(data)
    if magic != MAGIC:
        raise CheckpointError("not a map checkpoint (bad magic)")
    if hashlib.sha256(data[:-_DIGEST]).digest() != data[-_DIGEST:]:
        raise CheckpointError("checksum mismatch (truncated or corrupt)")
    if version not in READABLE_VERSIONS:
        raise CheckpointError(f"unsupported version {version} (this build reads {READABLE_VERSIONS})")
    if hlen > _MAX_HEADER or _HEAD.size + hlen > len(data) - _DIGEST:
        raise CheckpointError("header length out of range")
    try:
        h = json.loads(data[_HEAD.size:_HEAD.size + hlen])
        x0, y0, cell, nx, ny = h["grid"]
        grid = MapGrid(float(x0), float(y0), float(cell), int(nx), int(ny))
        rest = data[_HEAD.size + hlen:-_DIGEST]
        state_len = int(h["state_len"]) if version >= 2 else 0
        if not 0 <= state_len <= len(rest) or len(rest) - state_len != h["body_len"]:
            raise CheckpointError("body or state length does not match the header")
        body, state_z = rest[:len(rest) - state_len], rest[len(rest) - state_len:]
        raw = zstandard.ZstdDecompressor().decompress(body, max_output_size=int(h["raw_len"]))
        state = _decode_state(state_z, int(h.get("state_raw_len", 0))) if state_len else None
        names = [tuple(a) for a in h["arrays"]]
        seq, time_s, n_max = int(h["seq"]), float(h["time_s"]), int(h["n_max"])
    except CheckpointError:
        raise
    except (KeyError, TypeError, ValueError, zstandard.ZstdError) as exc:
        raise CheckpointError(f"malformed header or body ({exc})") from None
    if not (1 <= nx <= 8192 and 1 <= ny <= 8192 and cell > 0):
        raise CheckpointError(f"grid {nx}x{ny} cells of {cell} m is out of range")
    if names != [tuple(a) for a in _ARRAYS]:
        raise CheckpointError("unexpected array list")
    sizes = [nx * ny * np.dtype(dt).itemsize for _, dt in _ARRAYS]
    if len(raw) != sum(sizes):
        raise CheckpointError("array data has the wrong size for the grid")
    base = cfg or FusionConfig()
    if base.n_max != n_max:
        base = FusionConfig(**{**base.__dict__, "n_max": n_max})
    emap = ElevationMap(grid, base)
    off = 0
    for (name, dt), size in zip(_ARRAYS, sizes, strict=True):
        arr = np.frombuffer(raw, dtype=dt, count=nx * ny, offset=off).reshape(ny, nx)
        setattr(emap, name, arr.astype(np.dtype(dt).newbyteorder("=")))
        off += size
    return emap, CheckpointMeta(seq, time_s, state, version)


def _decode_state(state_z: bytes, raw_len: int) -> dict[str, Any]:
    if not 0 < raw_len <= _MAX_STATE:
        raise CheckpointError(f"mission state length {raw_len} out of range")
    raw = zstandard.ZstdDecompressor().decompress(state_z, max_output_size=raw_len)
    if len(raw) != raw_len:
        raise CheckpointError("mission state has the wrong length")
    state = json.loads(raw)
    if not isinstance(state, dict):
        raise CheckpointError("mission state is not an object")
    return state
