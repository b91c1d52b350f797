"""The relative-localization packets on the radio link (docs/team.md, "Relative localization").

The RECON-bot's fix of the Cliff-bot's pose (``CliffbotLocalizer``, docs/algorithm.md §5) and the
Cliff-bot's request for one share the map link's framing (``fsw.comm.link_packets``: magic
0xA5, version 1, a type nibble, a 16-bit session word, the body, a CRC-32 of everything
before it), with type numbers the map link does not use, so one radio carries both and a
receiver tells them apart by the type nibble. A fix is small (122 bytes) and is sent ahead
of map bytes. :func:`decode` raises :class:`~fsw.comm.link_packets.PacketError` with a
one-line reason on anything that is not an intact fix packet.

FIX_REQUEST body: ``seq`` u16, ``leg`` u16, the Cliff-bot's estimate ``x y`` f32 (where the
RECON-bot aims its mast) and its attitude sensor's ``roll pitch`` f32 in degrees (the gravity
the fix's attitude must agree with, docs/algorithm.md §5.3); a 12-byte body without the attitude and
a 4-byte body without either are still read (NaN). NO_FIX body: ``seq`` u16, ``reason`` u8.
FIX body: ``seq`` u16 (the request answered), ``t_ms`` u32 (RECON-bot clock), position
``x y z`` and rotation vector ``rx ry rz`` (body to world) as f32, and the fix's 6x6
covariance (rotation first, then position; docs/algorithm.md §5) as its 21-value upper triangle, f32.
"""

from __future__ import annotations

import math
import struct
import zlib
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fsw.comm.link_packets import MAGIC, VERSION, PacketError

F64 = NDArray[np.float64]
FIX_REQUEST, FIX, NO_FIX = 12, 13, 14
_REQ = struct.Struct("<HH")
_REQ_XY = struct.Struct("<HHff")
_REQ_ATT = struct.Struct("<HHffff")
_NO = struct.Struct("<HB")
NO_FIX_REASONS = ("no markers seen", "out of the mast's reach", "busy")
_FIX = struct.Struct("<HI6f21f")
_IU = np.triu_indices(6)


@dataclass(frozen=True)
class FixRequest:
    seq: int
    leg: int
    x: float = math.nan  # the Cliff-bot's estimate (map frame, m); NaN: not given
    y: float = math.nan
    roll_deg: float = math.nan  # its attitude sensor's roll (left side up +) and pitch (nose up +); NaN: not given
    pitch_deg: float = math.nan

    @property
    def attitude(self) -> tuple[float, float] | None:
        """Its roll and pitch in radians (the gravity its fix must agree with), None when not given."""
        if not (math.isfinite(self.roll_deg) and math.isfinite(self.pitch_deg)):
            return None
        return math.radians(self.roll_deg), math.radians(self.pitch_deg)


@dataclass(frozen=True)
class NoFix:
    """The RECON-bot's answer when it cannot localize the Cliff-bot (``reason``: an index
    into :data:`NO_FIX_REASONS`)."""

    seq: int
    reason: int


@dataclass(frozen=True)
class Fix:
    seq: int
    t_ms: int
    position: F64  # (3,) world metres
    rotvec: F64  # (3,) body-to-world rotation vector, rad
    cov: F64  # (6, 6): rotation (rad) then position (m)

    @property
    def yaw(self) -> float:
        """Heading of the body's x axis (rad)."""
        r = rotation(self.rotvec)
        return math.atan2(float(r[1, 0]), float(r[0, 0]))


def rotation(rv: F64) -> F64:
    """Rodrigues: the rotation matrix of a rotation vector."""
    th = float(np.linalg.norm(rv))
    if th < 1e-12:
        return np.eye(3)
    k = np.asarray(rv, float) / th
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.asarray(np.eye(3) + math.sin(th) * kx + (1 - math.cos(th)) * kx @ kx, float)


def _frame(ptype: int, body: bytes) -> bytes:
    msg = struct.pack("<BBH", MAGIC, (VERSION << 4) | ptype, 0) + body
    return msg + struct.pack("<I", zlib.crc32(msg))


def encode(p: Fix | FixRequest | NoFix) -> bytes:
    if isinstance(p, NoFix):
        return _frame(NO_FIX, _NO.pack(p.seq & 0xFFFF, p.reason & 0xFF))
    if isinstance(p, FixRequest):
        if not (math.isfinite(p.x) and math.isfinite(p.y)):
            return _frame(FIX_REQUEST, _REQ.pack(p.seq & 0xFFFF, p.leg & 0xFFFF))
        if p.attitude is None:
            return _frame(FIX_REQUEST, _REQ_XY.pack(p.seq & 0xFFFF, p.leg & 0xFFFF, p.x, p.y))
        return _frame(FIX_REQUEST, _REQ_ATT.pack(p.seq & 0xFFFF, p.leg & 0xFFFF, p.x, p.y, p.roll_deg, p.pitch_deg))
    vals = [*np.asarray(p.position, float), *np.asarray(p.rotvec, float), *np.asarray(p.cov, float)[_IU]]
    if not all(math.isfinite(v) for v in vals):
        raise ValueError("a fix with a non-finite value is not sent")
    return _frame(FIX, _FIX.pack(p.seq & 0xFFFF, p.t_ms & 0xFFFFFFFF, *vals))


def is_fix_packet(datagram: bytes) -> bool:
    """Whether a datagram's header names a fix type (the routing test; integrity is decode's)."""
    return len(datagram) >= 2 and datagram[0] == MAGIC and (datagram[1] & 0xF) in (FIX_REQUEST, FIX, NO_FIX)


def decode(datagram: bytes) -> Fix | FixRequest | NoFix:
    d = bytes(datagram)
    if len(d) < 8:
        raise PacketError(f"fix packet of {len(d)} bytes is too short")
    if d[0] != MAGIC or d[1] >> 4 != VERSION:
        raise PacketError("not a version-1 link packet")
    if struct.unpack("<I", d[-4:])[0] != zlib.crc32(d[:-4]):
        raise PacketError("fix packet CRC mismatch")
    ptype, body = d[1] & 0xF, d[4:-4]
    if ptype == FIX_REQUEST and len(body) == _REQ.size:
        seq, leg = _REQ.unpack(body)
        return FixRequest(seq, leg)
    if ptype == FIX_REQUEST and len(body) == _REQ_XY.size:
        seq, leg, x, y = _REQ_XY.unpack(body)
        if not (math.isfinite(x) and math.isfinite(y)):
            raise PacketError("fix request with a non-finite estimate")
        return FixRequest(seq, leg, float(x), float(y))
    if ptype == FIX_REQUEST and len(body) == _REQ_ATT.size:
        seq, leg, x, y, roll, pitch = _REQ_ATT.unpack(body)
        if not all(math.isfinite(v) for v in (x, y, roll, pitch)):
            raise PacketError("fix request with a non-finite estimate or attitude")
        if abs(roll) > 90.0 or abs(pitch) > 90.0:
            raise PacketError(f"fix request with an attitude out of range (roll {roll:.1f}, pitch {pitch:.1f} deg)")
        return FixRequest(seq, leg, float(x), float(y), float(roll), float(pitch))
    if ptype == NO_FIX and len(body) == _NO.size:
        seq, why = _NO.unpack(body)
        return NoFix(seq, why)
    if ptype == FIX and len(body) == _FIX.size:
        v = _FIX.unpack(body)
        cov = np.zeros((6, 6))
        cov[_IU] = v[8:]
        cov = cov + np.triu(cov, 1).T
        if not np.isfinite(cov).all() or not np.isfinite(v[2:8]).all():
            raise PacketError("fix with non-finite values")
        return Fix(int(v[0]), int(v[1]), np.array(v[2:5], float), np.array(v[5:8], float), cov)
    raise PacketError(f"type {ptype} with a {len(body)}-byte body is not a fix packet")
