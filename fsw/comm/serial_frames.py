"""Framed binary protocol of the mast controller's serial line, sans I/O (both ends use it).

Frame (all multi-byte fields little-endian except the CRC)::

    0xA5 0x5A | LEN | SEQ | TYPE | PAYLOAD (LEN bytes, <= 64) | CRC32 (big-endian)

``CRC32`` is CRC-32/ISO-HDLC (IEEE 802.3, poly 0x04C11DB7; ``zlib.crc32``) over
``LEN SEQ TYPE PAYLOAD``: Hamming distance >= 5 at these lengths (<= 568 bits, Koopman), so
every 1-4 bit error of SEQ, TYPE, payload or CRC is caught; an error in LEN or SYNC reframes
and is caught with probability 1 - 2^-32, and so is frame-shaped noise (the former CRC-16 let
2 of 25,000 random frames through in ``safer-hil bench e2e``). :class:`FrameDecoder` takes
bytes in any chunking and returns whole frames; on garbage, a bad CRC or an impossible length
it drops one byte and hunts for the next sync pair, so a corrupted frame never swallows the
good one behind it. A frame that is still incomplete (its LEN promises more bytes than have
arrived: a corrupted LEN, or a frame cut short) does not hold back a complete, CRC-valid frame
already in the buffer behind it: the decoder looks ahead, returns that frame and refuses the
incomplete one as ``truncated``. So a valid frame is returned as soon as its last byte arrives,
whatever garbage, cut or mutated frame came before it, and a frame cut by one byte whose CRC
ended in 0xA5 (completed by the next frame's sync byte) leaves that byte to the next frame.
What it can still lose, exactly: a frame whose own bytes are damaged, and a frame whose first
two or more bytes, with damaged bytes before them, form a CRC-valid frame (a frame cut by k >= 2
bytes that were the next frame's first k: probability 2^-8k, or a chance CRC match: 2^-32). It
counts what it threw away and never raises on line noise.

Messages (``TYPE``: payload):

=====  ===========  ====================================================================
0x01   MOVE         ``<iii`` pan [urad], tilt [urad], lift [um]; answered ACK or NAK
0x02   STOP         empty; hold the current position; ACK
0x03   QUERY        empty; answered by STATE
0x04   CLEAR_FAULT  empty; clear a latched stall fault; ACK
0x81   ACK          ``<BB`` acknowledged SEQ, acknowledged TYPE
0x82   NAK          ``<BBB`` refused SEQ, refused TYPE (0 if unreadable), reason (NAK_*)
0x83   STATE        ``<iiiB`` pan [urad], tilt [urad], lift [um], flags (STATE_*)
=====  ===========  ====================================================================
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass

SYNC = b"\xa5\x5a"
HEADER_LEN = 5  # sync(2) len seq type
CRC_LEN = 4
MAX_PAYLOAD = 64

MOVE, STOP, QUERY, CLEAR_FAULT, ACK, NAK, STATE = 0x01, 0x02, 0x03, 0x04, 0x81, 0x82, 0x83
TYPE_NAMES = {
    MOVE: "MOVE",
    STOP: "STOP",
    QUERY: "QUERY",
    CLEAR_FAULT: "CLEAR_FAULT",
    ACK: "ACK",
    NAK: "NAK",
    STATE: "STATE",
}
NAK_BAD_CRC, NAK_BAD_LENGTH, NAK_UNKNOWN_TYPE, NAK_OUT_OF_LIMITS, NAK_FAULTED = 1, 2, 3, 4, 5
NAK_REASONS = {
    NAK_BAD_CRC: "bad CRC",
    NAK_BAD_LENGTH: "bad length",
    NAK_UNKNOWN_TYPE: "unknown type",
    NAK_OUT_OF_LIMITS: "out of limits",
    NAK_FAULTED: "controller faulted",
}
STATE_MOVING, STATE_AT_TARGET, STATE_FAULT, STATE_LIMIT = 0x01, 0x02, 0x04, 0x08

_FORMATS = {MOVE: "<iii", STOP: "", QUERY: "", CLEAR_FAULT: "", ACK: "<BB", NAK: "<BBB", STATE: "<iiiB"}


def frame_crc(data: bytes) -> int:
    """CRC-32/ISO-HDLC (``zlib.crc32``)."""
    return zlib.crc32(data)


@dataclass(frozen=True)
class Frame:
    seq: int
    type: int
    payload: bytes


@dataclass(frozen=True)
class FrameError:
    """A frame-shaped thing that was refused: ``bad_crc`` or ``bad_length``; ``seq`` best effort."""

    reason: str
    seq: int
    type: int


def encode_frame(seq: int, type_: int, payload: bytes = b"") -> bytes:
    if len(payload) > MAX_PAYLOAD:
        raise ValueError(f"payload of {len(payload)} bytes exceeds {MAX_PAYLOAD}")
    body = bytes((len(payload), seq & 0xFF, type_ & 0xFF)) + payload
    return SYNC + body + frame_crc(body).to_bytes(CRC_LEN, "big")


class FrameDecoder:
    """Incremental frame parser with resynchronisation and counters."""

    def __init__(self, max_buffer: int = 4096) -> None:
        self._buf = bytearray()
        self.max_buffer = max_buffer
        self.frames = 0
        self.crc_errors = 0
        self.length_errors = 0
        self.garbage_bytes = 0
        self._kept = False

    def feed(self, data: bytes) -> list[Frame | FrameError]:
        """Add received bytes; return the frames (and refused frames) now complete."""
        self._buf += data
        out: list[Frame | FrameError] = []
        buf = self._buf
        while True:
            start = buf.find(SYNC)
            kept, self._kept = self._kept, False  # buf[0] is a frame's last byte, kept (below)
            if start < 0:
                keep = 1 if buf[-1:] == SYNC[:1] else 0  # a sync byte may be split across reads
                self.garbage_bytes += len(buf) - keep - (kept and len(buf) > keep)
                self._kept = kept and len(buf) == keep
                del buf[: len(buf) - keep]
                break
            if start:
                self.garbage_bytes += start - kept
                del buf[:start]
            if len(buf) < HEADER_LEN:
                break
            n, seq, typ = buf[2], buf[3], buf[4]
            if n > MAX_PAYLOAD:
                self.length_errors += 1
                out.append(FrameError("bad_length", seq, typ))
                del buf[:1]
                continue
            total = HEADER_LEN + n + CRC_LEN
            if len(buf) < total:
                nxt = self._complete_frame_after(buf)
                if nxt < 0:
                    break  # wait for the rest of this frame
                self.length_errors += 1  # cut short, or its LEN is wrong: the frame behind it is whole
                out.append(FrameError("truncated", seq, typ))
                self.garbage_bytes += nxt
                del buf[:nxt]
                continue
            body = bytes(buf[2 : HEADER_LEN + n])
            if frame_crc(body) != int.from_bytes(buf[HEADER_LEN + n : total], "big"):
                self.crc_errors += 1
                out.append(FrameError("bad_crc", seq, typ))
                del buf[:1]
                continue
            out.append(Frame(seq, typ, bytes(buf[HEADER_LEN : HEADER_LEN + n])))
            self.frames += 1
            # a frame that lost its last byte may have been completed by the 0xA5 that starts the
            # next frame: keep a last 0xA5 unless the next byte shows it was not a sync (a clean
            # stream has the next frame's 0xA5 there); a kept byte is not counted as garbage
            self._kept = buf[total - 1] == SYNC[0] and buf[total : total + 1] in (b"", SYNC[1:])
            del buf[: total - 1 if self._kept else total]
        if len(buf) > self.max_buffer:  # cannot happen with MAX_PAYLOAD frames; belt and braces
            self.garbage_bytes += len(buf)
            buf.clear()
        return out

    @staticmethod
    def _complete_frame_after(buf: bytearray) -> int:
        """Offset of the first later sync that starts a whole, CRC-valid frame (-1: none)."""
        pos = buf.find(SYNC, 1)
        while pos >= 0 and pos + HEADER_LEN <= len(buf):
            n = buf[pos + 2]
            end = pos + HEADER_LEN + n + CRC_LEN
            if n <= MAX_PAYLOAD and end <= len(buf):
                crc = int.from_bytes(buf[end - CRC_LEN : end], "big")
                if frame_crc(bytes(buf[pos + 2 : pos + HEADER_LEN + n])) == crc:
                    return pos
            pos = buf.find(SYNC, pos + 1)
        return -1


# -- messages -------------------------------------------------------------------------------
@dataclass(frozen=True)
class Move:
    pan_rad: float
    tilt_rad: float
    lift_m: float


@dataclass(frozen=True)
class Stop:
    pass


@dataclass(frozen=True)
class Query:
    pass


@dataclass(frozen=True)
class ClearFault:
    pass


@dataclass(frozen=True)
class Ack:
    seq: int
    type: int


@dataclass(frozen=True)
class Nak:
    seq: int
    type: int
    reason: int


@dataclass(frozen=True)
class MastState:
    pan_rad: float
    tilt_rad: float
    lift_m: float
    flags: int


Message = Move | Stop | Query | ClearFault | Ack | Nak | MastState
_TYPE_OF = {Move: MOVE, Stop: STOP, Query: QUERY, ClearFault: CLEAR_FAULT, Ack: ACK, Nak: NAK, MastState: STATE}


def _micro(v: float) -> int:
    return max(-(2**31), min(2**31 - 1, round(v * 1e6)))


def encode_message(msg: Message, seq: int) -> bytes:
    """One message as a complete frame."""
    t = _TYPE_OF[type(msg)]
    if isinstance(msg, Move):
        payload = struct.pack("<iii", _micro(msg.pan_rad), _micro(msg.tilt_rad), _micro(msg.lift_m))
    elif isinstance(msg, MastState):
        payload = struct.pack("<iiiB", _micro(msg.pan_rad), _micro(msg.tilt_rad), _micro(msg.lift_m), msg.flags & 0xFF)
    elif isinstance(msg, Ack):
        payload = struct.pack("<BB", msg.seq & 0xFF, msg.type & 0xFF)
    elif isinstance(msg, Nak):
        payload = struct.pack("<BBB", msg.seq & 0xFF, msg.type & 0xFF, msg.reason & 0xFF)
    else:
        payload = b""
    return encode_frame(seq, t, payload)


def parse_message(frame: Frame) -> Message | FrameError:
    """The message in a CRC-valid frame, or ``FrameError('unknown_type'|'bad_length')``."""
    fmt = _FORMATS.get(frame.type)
    if fmt is None:
        return FrameError("unknown_type", frame.seq, frame.type)
    if len(frame.payload) != struct.calcsize(fmt):
        return FrameError("bad_length", frame.seq, frame.type)
    v = struct.unpack(fmt, frame.payload) if fmt else ()
    t = frame.type
    if t == MOVE:
        return Move(v[0] * 1e-6, v[1] * 1e-6, v[2] * 1e-6)
    if t == STATE:
        return MastState(v[0] * 1e-6, v[1] * 1e-6, v[2] * 1e-6, v[3])
    if t == ACK:
        return Ack(v[0], v[1])
    if t == NAK:
        return Nak(v[0], v[1], v[2])
    empty: dict[int, Message] = {STOP: Stop(), QUERY: Query(), CLEAR_FAULT: ClearFault()}
    return empty[t]
