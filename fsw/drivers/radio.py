"""The inter-robot radio: a datagram port over three transports (ALGORITHM.md §6.6).

:class:`RadioPort` is the template (python-can ``BusABC`` style): the base class does the
counting, size checks and fault flags, a backend implements ``_send_internal`` and
``_recv_internal``. :func:`open_radio` picks the backend from one URL:

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

Transient errors never raise: they set a held fault bit, count and queue an event.
"""

from __future__ import annotations

import select
import socket
import threading
from collections import deque
from dataclasses import dataclass
from typing import Any, ClassVar
from urllib.parse import urlsplit

from cobs import cobs

from fsw.drivers.base import DriverBase
from fsw.framework.telemetry import EventDef, Severity

MAX_DATAGRAM = 8192


@dataclass
class RadioStats:
    tx_packets: int = 0
    tx_bytes: int = 0
    rx_packets: int = 0
    rx_bytes: int = 0
    tx_errors: int = 0
    rx_errors: int = 0  # framing errors, oversize frames, socket errors


class RadioPort(DriverBase):
    """A packet radio; ``send`` one datagram, ``recv`` one whole datagram or None."""

    EVENTS: ClassVar[tuple[EventDef, ...]] = (
        EventDef("RADIO_TX_ERROR", Severity.WARNING_LO, "radio {url}: send failed: {error}", throttle=5),
        EventDef("RADIO_RX_ERROR", Severity.WARNING_LO, "radio {url}: receive error: {error}", throttle=5),
    )
    FAULTS: ClassVar[dict[str, int]] = {"TX_ERROR": 1, "RX_ERROR": 2, "CLOSED": 4}

    def __init__(self, url: str) -> None:
        super().__init__()
        self.url = url
        self.stats = RadioStats()
        self.closed = False

    def send(self, datagram: bytes, now_s: float = 0.0) -> bool:
        """Queue one datagram for transmission; False (and a fault) if it could not be sent."""
        if self.closed or len(datagram) > MAX_DATAGRAM:
            return self._tx_error("port closed" if self.closed else
                                  f"{len(datagram)}-byte datagram over {MAX_DATAGRAM}", now_s)
        try:
            self._send_internal(bytes(datagram))
        except (OSError, ValueError) as exc:
            return self._tx_error(str(exc), now_s)
        self.stats.tx_packets += 1
        self.stats.tx_bytes += len(datagram)
        self._expire_holds(now_s)
        return True

    def recv(self, timeout_s: float = 0.0, now_s: float = 0.0) -> bytes | None:
        """The next whole datagram, waiting up to ``timeout_s``; None if there is none."""
        if self.closed:
            return None
        try:
            data = self._recv_internal(timeout_s)
        except (OSError, ValueError) as exc:
            self.stats.rx_errors += 1
            self._hold(self.FAULTS["RX_ERROR"], now_s)
            self._event("RADIO_RX_ERROR", url=self.url, error=str(exc))
            return None
        if data is not None:
            self.stats.rx_packets += 1
            self.stats.rx_bytes += len(data)
        return data

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            self._set(self.FAULTS["CLOSED"])
            self._close_internal()

    def __enter__(self) -> RadioPort:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _tx_error(self, error: str, now_s: float) -> bool:
        self.stats.tx_errors += 1
        self._hold(self.FAULTS["TX_ERROR"], now_s)
        self._event("RADIO_TX_ERROR", url=self.url, error=error)
        return False

    # -- backends ---------------------------------------------------------------------------
    def _send_internal(self, datagram: bytes) -> None:
        raise NotImplementedError

    def _recv_internal(self, timeout_s: float) -> bytes | None:
        raise NotImplementedError

    def _close_internal(self) -> None:
        """Release the device (nothing by default)."""


class InProcRadio(RadioPort):
    """One end of an in-process pair (thread-safe deques)."""

    _registry: ClassVar[dict[str, list[InProcRadio]]] = {}
    _lock = threading.Lock()

    def __init__(self, name: str) -> None:
        super().__init__(f"inproc://{name}")
        self.inbox: deque[bytes] = deque(maxlen=4096)
        self._cond = threading.Condition()
        self.peer: InProcRadio | None = None
        with InProcRadio._lock:
            ends = InProcRadio._registry.setdefault(name, [])
            if len(ends) >= 2:
                raise ValueError(f"inproc://{name} already has two ends")
            ends.append(self)
            if len(ends) == 2:
                ends[0].peer, ends[1].peer = ends[1], ends[0]
        self._name = name

    @classmethod
    def pair(cls, name: str) -> tuple[InProcRadio, InProcRadio]:
        return cls(name), cls(name)

    def _send_internal(self, datagram: bytes) -> None:
        peer = self.peer
        if peer is None or peer.closed:
            raise OSError("no peer connected")
        with peer._cond:
            peer.inbox.append(datagram)
            peer._cond.notify()

    def _recv_internal(self, timeout_s: float) -> bytes | None:
        with self._cond:
            if not self.inbox and timeout_s > 0:
                self._cond.wait(timeout_s)
            return self.inbox.popleft() if self.inbox else None

    def _close_internal(self) -> None:
        with InProcRadio._lock:
            ends = InProcRadio._registry.get(self._name, [])
            if self in ends:
                ends.remove(self)
            if not ends:
                InProcRadio._registry.pop(self._name, None)


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


class UdpRadio(RadioPort):
    """A UDP socket: each datagram is one packet."""

    def __init__(self, url: str, peer: str = "") -> None:
        super().__init__(url)
        host, port = parse_udp(url)
        self._peer: tuple[str, int] | None = parse_udp(peer) if peer else None
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setblocking(False)
        self.sock.bind((host, port))

    @property
    def address(self) -> tuple[str, int]:
        addr: Any = self.sock.getsockname()
        return addr[0], addr[1]

    def _send_internal(self, datagram: bytes) -> None:
        if self._peer is None:
            raise OSError("no peer yet (set peer, or wait for the first datagram)")
        self.sock.sendto(datagram, self._peer)

    def _recv_internal(self, timeout_s: float) -> bytes | None:
        if timeout_s > 0:
            ready, _, _ = select.select([self.sock], [], [], timeout_s)
            if not ready:
                return None
        try:
            data, addr = self.sock.recvfrom(65535)
        except BlockingIOError:
            return None
        self._peer = self._peer or (addr[0], addr[1])
        return data

    def _close_internal(self) -> None:
        self.sock.close()


class SerialRadio(RadioPort):
    """A serial radio modem through pyserial, COBS-framed packets."""

    def __init__(self, port: str, baud: int = 9600, max_buffer: int = 65536,
                 ser: Any = None) -> None:
        """Open ``port`` at ``baud``, or use ``ser``, an already open pyserial-like object."""
        super().__init__(f"serial:{port}@{baud}")
        if ser is None:
            import serial  # pyserial; imported here so other transports do not need it

            ser = serial.serial_for_url(port, baudrate=baud, timeout=0, write_timeout=1.0)
        self.ser = ser
        self._buf = bytearray()
        self._frames: deque[bytes] = deque()
        self._max_buffer = max_buffer

    def _send_internal(self, datagram: bytes) -> None:
        self.ser.write(cobs.encode(datagram) + b"\x00")

    def _recv_internal(self, timeout_s: float) -> bytes | None:
        if not self._frames:
            self.ser.timeout = timeout_s
            chunk = self.ser.read(max(1, self.ser.in_waiting))
            self.ser.timeout = 0
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

    def _close_internal(self) -> None:
        self.ser.close()


def open_radio(url: str, peer: str = "") -> RadioPort:
    """Open the radio named by ``url`` (see the module docstring); ValueError if malformed."""
    if url.startswith("inproc://") and len(url) > len("inproc://"):
        return InProcRadio(url[len("inproc://"):])
    if url.startswith("udp://"):
        return UdpRadio(url, peer)
    if url.startswith("serial:") and len(url) > len("serial:"):
        port, sep, baud = url[len("serial:"):].rpartition("@")
        if sep and baud.isdigit():
            return SerialRadio(port, int(baud))
        return SerialRadio(url[len("serial:"):])
    raise ValueError(f"radio URL {url!r}: expected inproc://NAME, udp://HOST:PORT or serial:PORT[@BAUD]")
