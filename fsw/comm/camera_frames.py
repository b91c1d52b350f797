"""Camera socket protocol, sans I/O: capture requests and stereo-pair replies.

Used by the flight camera driver's socket backend (``fsw.drivers.camera``) and the bench's
camera server (``hil_sim.hw.camera_server``) in multi-process mode.

* Request, client -> server, 8 bytes: ``b"CAMQ"`` then ``<I`` sequence number.
* Reply, server -> client: a 31-byte header ``<4sIBHHdII`` = ``b"CAMF"``, sequence, status
  (``OK`` 0, ``DROPOUT`` 1: no frame this time, ``UNAVAILABLE`` 2: the server cannot render),
  width, height, capture time [s, bench clock], payload length, CRC-32 of the payload; then the
  payload: the left image then the right image, ``uint8`` grayscale, row-major (empty unless OK).

The decoders accept bytes in any chunking, resynchronise on the magic after garbage and refuse
(count, never raise on) a header with an impossible size or a payload whose CRC fails.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

REQ_MAGIC, REPLY_MAGIC = b"CAMQ", b"CAMF"
REQ_FMT, HDR_FMT = "<4sI", "<4sIBHHdII"
REQ_LEN, HDR_LEN = struct.calcsize(REQ_FMT), struct.calcsize(HDR_FMT)
OK, DROPOUT, UNAVAILABLE = 0, 1, 2
STATUS_NAMES = {OK: "OK", DROPOUT: "DROPOUT", UNAVAILABLE: "UNAVAILABLE"}
MAX_SIDE_PX = 4096

U8 = NDArray[np.uint8]


@dataclass(frozen=True)
class CameraReply:
    seq: int
    status: int
    t_capture_s: float
    left: U8 | None
    right: U8 | None


def encode_request(seq: int) -> bytes:
    return struct.pack(REQ_FMT, REQ_MAGIC, seq & 0xFFFFFFFF)


def encode_reply(seq: int, status: int, t_capture_s: float, left: U8 | None = None, right: U8 | None = None) -> bytes:
    if status == OK:
        if left is None or right is None or left.shape != right.shape or left.ndim != 2:
            raise ValueError("an OK reply needs two 2-D images of one shape")
        h, w = left.shape
        payload = np.ascontiguousarray(left, np.uint8).tobytes() + np.ascontiguousarray(right, np.uint8).tobytes()
    else:
        h = w = 0
        payload = b""
    hdr = struct.pack(
        HDR_FMT, REPLY_MAGIC, seq & 0xFFFFFFFF, status, w, h, float(t_capture_s), len(payload), zlib.crc32(payload)
    )
    return hdr + payload


class _Resync:
    def __init__(self, magic: bytes) -> None:
        self.magic = magic
        self.buf = bytearray()
        self.garbage_bytes = 0

    def _align(self) -> bool:
        i = self.buf.find(self.magic)
        if i < 0:
            keep = len(self.magic) - 1
            drop = max(0, len(self.buf) - keep)
            self.garbage_bytes += drop
            del self.buf[:drop]
            return False
        self.garbage_bytes += i
        del self.buf[:i]
        return True


class RequestDecoder(_Resync):
    """Server side: sequence numbers of complete requests."""

    def __init__(self) -> None:
        super().__init__(REQ_MAGIC)

    def feed(self, data: bytes) -> list[int]:
        self.buf += data
        out = []
        while self._align() and len(self.buf) >= REQ_LEN:
            _, seq = struct.unpack(REQ_FMT, self.buf[:REQ_LEN])
            out.append(int(seq))
            del self.buf[:REQ_LEN]
        return out


class ReplyDecoder(_Resync):
    """Client side: complete replies; ``errors`` counts refused headers and payloads."""

    def __init__(self) -> None:
        super().__init__(REPLY_MAGIC)
        self.errors = 0

    def feed(self, data: bytes) -> list[CameraReply]:
        self.buf += data
        out = []
        while self._align() and len(self.buf) >= HDR_LEN:
            _, seq, status, w, h, t, n, crc = struct.unpack(HDR_FMT, self.buf[:HDR_LEN])
            ok_size = status == OK and 0 < w <= MAX_SIDE_PX and 0 < h <= MAX_SIDE_PX and n == 2 * w * h
            if not (ok_size or (status in (DROPOUT, UNAVAILABLE) and n == 0)):
                self.errors += 1
                del self.buf[:1]  # not a real header: hunt for the next magic
                continue
            if len(self.buf) < HDR_LEN + n:
                break
            payload = bytes(self.buf[HDR_LEN : HDR_LEN + n])
            del self.buf[: HDR_LEN + n]
            if zlib.crc32(payload) != crc:
                self.errors += 1
                continue
            if status == OK:
                img = np.frombuffer(payload, np.uint8).reshape(2, h, w)
                out.append(CameraReply(int(seq), OK, float(t), img[0], img[1]))
            else:
                out.append(CameraReply(int(seq), int(status), float(t), None, None))
        return out
