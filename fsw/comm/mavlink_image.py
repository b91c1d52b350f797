"""MAVLink image transfer: an encoded image as DATA_TRANSMISSION_HANDSHAKE + ENCAPSULATED_DATA.

Sans-I/O on both ends. The sender announces an image with one handshake (type, total size,
width, height, packet count, 253-byte payload, quality) and then streams its packets
``seqnr = 0 .. packets-1`` as the downlink budget allows (lowest priority). The receiver
(the ground's ``map`` tool and live view) reassembles them; a new handshake closes the
previous image, complete or not, so a lost packet costs one preview, never the stream.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from fsw.comm.mavlink_dialect import mavlink

CHUNK_BYTES = 253
MAX_PACKETS = 65535


@dataclass(frozen=True)
class ImageInfo:
    kind: int  # MAVLINK_DATA_STREAM_IMG_*
    size: int
    width: int
    height: int
    packets: int
    quality: int


class ImageSender:
    """Streams one image at a time; :meth:`offer` a new one when :attr:`busy` is False."""

    def __init__(self) -> None:
        self.info: ImageInfo | None = None
        self._data = b""
        self._next = -1  # -1: handshake pending, else the next packet's seqnr
        self.images_started = 0
        self.images_sent = 0
        self.packets_sent = 0

    @property
    def busy(self) -> bool:
        return self.info is not None

    def offer(self, data: bytes, width: int, height: int, kind: int, quality: int) -> None:
        packets = -(-len(data) // CHUNK_BYTES)
        if not data or packets > MAX_PACKETS:
            raise ValueError(f"image of {len(data)} bytes cannot be sent ({packets} packets)")
        self.info = ImageInfo(kind, len(data), width, height, packets, quality)
        self._data, self._next = bytes(data), -1
        self.images_started += 1

    def peek(self) -> mavlink.MAVLink_message | None:
        """The next message of the transfer (not yet consumed)."""
        info = self.info
        if info is None:
            return None
        if self._next < 0:
            return mavlink.MAVLink_data_transmission_handshake_message(
                info.kind, info.size, info.width, info.height, info.packets, CHUNK_BYTES, info.quality)
        chunk = self._data[self._next * CHUNK_BYTES:(self._next + 1) * CHUNK_BYTES]
        return mavlink.MAVLink_encapsulated_data_message(self._next, chunk.ljust(CHUNK_BYTES, b"\x00"))

    def consume(self) -> None:
        """The message from :meth:`peek` went out."""
        if self.info is None:
            return
        if self._next >= 0:
            self.packets_sent += 1
        self._next += 1
        if self._next >= self.info.packets:
            self.info, self._data = None, b""
            self.images_sent += 1


@dataclass
class ReceivedImage:
    info: ImageInfo
    data: bytes
    time_s: float
    missing: int

    @property
    def complete(self) -> bool:
        return self.missing == 0


@dataclass
class ImageReceiver:
    """Reassembles images from a message stream (any source: a link or a .tlog)."""

    images: list[ReceivedImage] = field(default_factory=list)
    _info: ImageInfo | None = None
    _chunks: dict[int, bytes] = field(default_factory=dict)
    _t0: float = 0.0
    stray_packets: int = 0

    def feed(self, msg: mavlink.MAVLink_message, time_s: float = 0.0) -> ReceivedImage | None:
        """Feed one message; returns an image when one completes (or is closed incomplete)."""
        kind = msg.get_type()
        if kind == "DATA_TRANSMISSION_HANDSHAKE":
            if msg.packets <= 0 or msg.size <= 0 or msg.payload <= 0:
                return None  # a request from a ground station, not an announcement
            closed = self.close()
            self._info = ImageInfo(msg.type, msg.size, msg.width, msg.height, msg.packets, msg.jpg_quality)
            self._chunks, self._t0 = {}, time_s
            return closed
        if kind == "ENCAPSULATED_DATA":
            if self._info is None or not 0 <= msg.seqnr < self._info.packets:
                self.stray_packets += 1
                return None
            self._chunks[msg.seqnr] = bytes(msg.data).ljust(CHUNK_BYTES, b"\x00")[:CHUNK_BYTES]
            if len(self._chunks) == self._info.packets:
                return self.close()
        return None

    def close(self) -> ReceivedImage | None:
        """Finish the image in progress (missing packets are zero-filled and counted)."""
        info = self._info
        if info is None:
            return None
        blob = b"".join(self._chunks.get(i, b"\x00" * CHUNK_BYTES) for i in range(info.packets))
        img = ReceivedImage(info, blob[:info.size], self._t0, info.packets - len(self._chunks))
        self.images.append(img)
        self._info, self._chunks = None, {}
        return img
