"""The inter-robot radio: a datagram port over three transports (docs/algorithm.md §6.6).

The radio is a :class:`~fsw.drivers.byte_port.BytePort` that carries whole datagrams of at
most ``MAX_DATAGRAM`` bytes (the base class counts, checks sizes, raises fault bits and
events, takes ``now`` from the caller). :func:`open_radio` picks the backend from one URL:

``inproc://NAME``
    In-process endpoints for lockstep runs and tests: the first open of a name is side A,
    the second side B; each receives what the other sends, in order, unimpaired.
``udp://HOST:PORT``
    A UDP socket bound to HOST:PORT; datagrams go to ``peer`` (``udp://HOST:PORT``) or, if
    none is given, back to whoever sent the last datagram. One datagram = one packet.
``serial:PORT[@BAUD]``
    A serial radio modem through pyserial (``PORT`` is a device such as ``/dev/ttyUSB0``
    or a pyserial URL such as ``loop://`` or ``socket://HOST:PORT``). Packets are COBS
    framed with a 0x00 delimiter, so the reader resynchronises on the next delimiter after
    line noise; the link protocol's CRC-32 rejects whatever noise still gets through.
"""

from __future__ import annotations

from collections import deque
from urllib.parse import urlsplit

from cobs import cobs

from fsw.drivers.byte_port import BytePort, InProcPort, SerialLike, SerialPort, UdpPort

MAX_DATAGRAM = 8192

RadioPort = BytePort  # what the radio task and the Cliff-bot bench hold: a datagram port


def parse_udp(url: str) -> tuple[str, int]:
    """``udp://HOST:PORT`` -> (host, port); ValueError with the reason otherwise."""
    parts = urlsplit(url)
    try:
        port = parts.port
    except ValueError:
        port = None
    if parts.scheme != "udp" or not parts.hostname or port is None:
        raise ValueError(f"{url!r}: expected udp://HOST:PORT")
    return parts.hostname, port


class SerialRadio(SerialPort):
    """A serial radio modem: COBS-framed datagrams on the byte stream of :class:`SerialPort`."""

    packetized = True

    def __init__(self, port: str, baud: int = 9600, max_buffer: int = 65536, ser: SerialLike | None = None) -> None:
        super().__init__(port, baud, ser=ser, max_send_bytes=MAX_DATAGRAM)
        self._buf = bytearray()
        self._frames: deque[bytes] = deque()
        self._max_buffer = max_buffer

    def _send_internal(self, data: bytes) -> None:
        super()._send_internal(cobs.encode(data) + b"\x00")

    def _recv_internal(self, timeout_s: float, max_bytes: int) -> bytes | None:
        if not self._frames:
            chunk = super()._recv_internal(timeout_s, max(4096, self._max_buffer - len(self._buf)))
            if chunk:
                self._buf += chunk
                self._split()
        return self._frames.popleft() if self._frames else None

    def _split(self) -> None:
        *frames, rest = bytes(self._buf).split(b"\x00")
        self._buf = bytearray(rest)
        if len(self._buf) > self._max_buffer:  # no delimiter for too long: line garbage
            self._buf.clear()
            self.stats.rx_errors += 1
        for f in frames:
            if not f:
                continue
            try:
                self._frames.append(cobs.decode(f))
            except cobs.DecodeError:
                self.stats.rx_errors += 1  # noise; the next delimiter resynchronises


def open_radio(url: str, peer: str = "") -> BytePort:
    """Open the radio named by ``url`` (see the module docstring); ValueError if malformed."""
    if url.startswith("inproc://") and len(url) > len("inproc://"):
        return InProcPort(url[len("inproc://"):], MAX_DATAGRAM)
    if url.startswith("udp://"):
        return UdpPort(url, parse_udp(url), parse_udp(peer) if peer else None, max_peers=1,
                       peer_timeout_s=float("inf"), max_send_bytes=MAX_DATAGRAM)
    if url.startswith("serial:") and len(url) > len("serial:"):
        port, sep, baud = url[len("serial:"):].rpartition("@")
        if sep and baud.isdigit():
            return SerialRadio(port, int(baud))
        return SerialRadio(url[len("serial:"):])
    raise ValueError(f"radio URL {url!r}: expected inproc://NAME, udp://HOST:PORT or serial:PORT[@BAUD]")
