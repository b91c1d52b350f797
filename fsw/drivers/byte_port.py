"""One byte port for every link that moves bytes: the inter-robot radio and the ground link.

:class:`BytePort` is the template (python-can ``BusABC`` style): the base class does what
every transport needs - counters, size checks, fault bits and events (``DriverBase``), the
time from the caller (the executive's clock, never ``time.monotonic()``: a lockstep bench
steps it), close and a lost device reopened after ``reopen_s`` - and a backend moves the
bytes with ``_send_internal``, ``_recv_internal`` and, if it can, ``_reopen_internal``.

Backends here:

* :class:`InProcPort` - in-process pairs for lockstep runs and tests;
* :class:`UdpPort` - a UDP socket, one datagram per packet: bound (answering the peers it
  heard) or sending to a fixed peer; an ICMP "port unreachable" is counted, not a fault;
* :class:`SerialPort` - a serial line through pyserial, a byte stream (``packetized`` is
  False); unplugging it is the ``LOST`` fault, and it is reopened every ``reopen_s``.

The radio (``fsw.drivers.radio``) frames datagrams over a serial modem with COBS on top of
:class:`SerialPort`; the ground link (``fsw.drivers.mavlink_transport``) opens these ports
from pymavlink-style URLs. Transient errors never raise: they set a held fault bit, count,
queue an event and leave a one-line ``fault_reason``.
"""

from __future__ import annotations

import contextlib
import ipaddress
import select
import socket
import threading
from collections import deque
from dataclasses import dataclass
from typing import ClassVar, Protocol

from fsw.drivers.base import DriverBase
from fsw.framework.telemetry import EventDef, Severity

UDP_MAX = 65507  # the largest UDP payload over IPv4


@dataclass
class PortStats:
    tx_packets: int = 0
    tx_bytes: int = 0
    rx_packets: int = 0
    rx_bytes: int = 0
    tx_errors: int = 0
    rx_errors: int = 0  # framing errors, oversize frames, device errors
    no_peer: int = 0  # sends with nobody to send to yet (a bound UDP port before the first datagram)
    refused: int = 0  # ICMP port unreachable: nobody listens at the peer (yet)
    reopens: int = 0


class PortLost(OSError):
    """Raised by a backend when its device is gone (unplugged, closed under it)."""


class NoPeer(OSError):
    """Raised by a backend's send when it has nobody to send to yet: not a fault."""


class BytePort(DriverBase):
    """A port that sends and receives bytes; see the module docstring."""

    EVENTS: ClassVar[tuple[EventDef, ...]] = (
        EventDef("TX_ERROR", Severity.WARNING_LO, "{url}: send failed: {error}", throttle=5),
        EventDef("RX_ERROR", Severity.WARNING_LO, "{url}: receive error: {error}", throttle=5),
        EventDef("LOST", Severity.WARNING_HI, "{url}: device lost: {error}; reopening every {reopen_s} s"),
        EventDef("REOPENED", Severity.ACTIVITY_HI, "{url}: device reopened"),
    )
    FAULTS: ClassVar[dict[str, int]] = {"TX_ERROR": 1, "RX_ERROR": 2, "CLOSED": 4, "LOST": 8}
    packetized: bool = True  # one receive = one whole datagram; False: a byte stream

    def __init__(self, url: str, max_send_bytes: int = UDP_MAX, reopen_s: float = 2.0) -> None:
        super().__init__()
        self.url = url
        self.max_send_bytes = max_send_bytes
        self.reopen_s = reopen_s
        self.stats = PortStats()
        self.closed = False
        self.fault_reason: str | None = None  # the last error, one line; None after a good send
        self._lost_until: float | None = None  # a lost device: the time of the next reopen try

    # -- the interface -------------------------------------------------------------------------
    def send(self, data: bytes, now_s: float = 0.0) -> bool:
        """Send one packet (a datagram, or bytes on a stream); False if it was not sent."""
        self.last_poll_s = now_s
        self._expire_holds(now_s)
        if self.closed or len(data) > self.max_send_bytes:
            return self._error("TX_ERROR", "port closed" if self.closed else
                               f"{len(data)}-byte packet over {self.max_send_bytes}", now_s)
        if not self._device_up(now_s):
            self.stats.tx_errors += 1
            return False
        try:
            self._send_internal(bytes(data))
        except NoPeer:
            self.stats.no_peer += 1
            return False
        except PortLost as exc:
            self._lost(exc, now_s)
            self.stats.tx_errors += 1
            return False
        except (OSError, ValueError) as exc:
            return self._error("TX_ERROR", str(exc), now_s)
        self.stats.tx_packets += 1
        self.stats.tx_bytes += len(data)
        self.fault_reason = None
        return True

    def recv(self, timeout_s: float = 0.0, now_s: float = 0.0, max_bytes: int = UDP_MAX) -> bytes | None:
        """The next datagram (or the bytes waiting on a stream, at most ``max_bytes``),
        waiting up to ``timeout_s``; None if there is none."""
        self.last_poll_s = now_s
        self._expire_holds(now_s)
        if self.closed or not self._device_up(now_s):
            return None
        try:
            data = self._recv_internal(timeout_s, max_bytes)
        except PortLost as exc:
            self._lost(exc, now_s)
            return None
        except (OSError, ValueError) as exc:
            self._error("RX_ERROR", str(exc), now_s)
            return None
        if data is not None:
            self.stats.rx_packets += 1
            self.stats.rx_bytes += len(data)
        return data

    def recv_upto(self, max_bytes: int, now_s: float) -> list[bytes]:
        """Everything waiting now, at most about ``max_bytes``: datagrams, or stream chunks."""
        chunks: list[bytes] = []
        n = 0
        while n < max_bytes:
            data = self.recv(0.0, now_s, max_bytes - n)
            if data is None:
                break
            chunks.append(data)
            n += len(data)
        return chunks

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            self._set(self.FAULTS["CLOSED"])
            self._close_internal()

    def __enter__(self) -> BytePort:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- errors and a lost device ----------------------------------------------------------------
    def _error(self, kind: str, error: str, now_s: float) -> bool:
        if kind == "TX_ERROR":
            self.stats.tx_errors += 1
        else:
            self.stats.rx_errors += 1
        self.fault_reason = f"{'send' if kind == 'TX_ERROR' else 'recv'}: {error}"
        self._hold(self.FAULTS[kind], now_s)
        self._event(kind, url=self.url, error=error)
        return False

    def _lost(self, exc: Exception, now_s: float) -> None:
        self.fault_reason = f"lost: {exc}"
        self._set(self.FAULTS["LOST"])
        self._event("LOST", url=self.url, error=str(exc), reopen_s=self.reopen_s)
        with contextlib.suppress(Exception):  # closing a dead device
            self._close_internal()
        self._lost_until = now_s + self.reopen_s

    def _device_up(self, now_s: float) -> bool:
        """True unless the device is lost; a lost one is reopened once ``reopen_s`` has passed."""
        if self._lost_until is None:
            return True
        if now_s < self._lost_until:
            return False
        try:
            self._reopen_internal()
        except (OSError, ValueError) as exc:
            self.fault_reason = f"reopen: {exc}"
            self._lost_until = now_s + self.reopen_s
            return False
        self._lost_until = None
        self._set(self.FAULTS["LOST"], False)
        self.stats.reopens += 1
        self.fault_reason = None
        self._event("REOPENED", url=self.url)
        return True

    # -- backends ---------------------------------------------------------------------------------
    def _send_internal(self, data: bytes) -> None:
        raise NotImplementedError

    def _recv_internal(self, timeout_s: float, max_bytes: int) -> bytes | None:
        raise NotImplementedError

    def _close_internal(self) -> None:
        """Release the device (nothing by default)."""

    def _reopen_internal(self) -> None:
        """Open the device again after it was lost; raise OSError if it is still gone."""
        raise OSError("this port cannot be reopened")


class InProcPort(BytePort):
    """One end of an in-process pair (thread-safe deques): the first open of a name is side
    A, the second side B; each receives what the other sends, in order, unimpaired."""

    _registry: ClassVar[dict[str, list[InProcPort]]] = {}
    _lock = threading.Lock()

    def __init__(self, name: str, max_send_bytes: int = UDP_MAX) -> None:
        super().__init__(f"inproc://{name}", max_send_bytes)
        self.inbox: deque[bytes] = deque(maxlen=4096)
        self._cond = threading.Condition()
        self.peer: InProcPort | None = None
        with InProcPort._lock:
            ends = InProcPort._registry.setdefault(name, [])
            if len(ends) >= 2:
                raise ValueError(f"inproc://{name} already has two ends")
            ends.append(self)
            if len(ends) == 2:
                ends[0].peer, ends[1].peer = ends[1], ends[0]
        self._name = name

    @classmethod
    def pair(cls, name: str, max_send_bytes: int = UDP_MAX) -> tuple[InProcPort, InProcPort]:
        return cls(name, max_send_bytes), cls(name, max_send_bytes)

    def _send_internal(self, data: bytes) -> None:
        peer = self.peer
        if peer is None or peer.closed:
            raise OSError("no peer connected")
        with peer._cond:
            peer.inbox.append(data)
            peer._cond.notify()

    def _recv_internal(self, timeout_s: float, max_bytes: int) -> bytes | None:
        with self._cond:
            if not self.inbox and timeout_s > 0:
                self._cond.wait(timeout_s)
            return self.inbox.popleft() if self.inbox else None

    def _close_internal(self) -> None:
        with InProcPort._lock:
            ends = InProcPort._registry.get(self._name, [])
            if self in ends:
                ends.remove(self)
            if not ends:
                InProcPort._registry.pop(self._name, None)


class UdpPort(BytePort):
    """A UDP socket: one datagram per packet.

    ``bind`` given: the socket listens there and, without a fixed ``peer``, answers the
    peers it heard from in the last ``peer_timeout_s`` (at most ``max_peers``, the oldest
    dropped first). ``peer`` given: every datagram goes there, and its replies are accepted.
    """

    def __init__(self, url: str, bind: tuple[str, int] | None, peer: tuple[str, int] | None = None,
                 max_peers: int = 8, peer_timeout_s: float = 30.0, max_send_bytes: int = UDP_MAX) -> None:
        super().__init__(url, max_send_bytes)
        self.peer = peer
        self.max_peers, self.peer_timeout_s = max_peers, peer_timeout_s
        self.peers: dict[tuple[str, int], float] = {}  # peers heard (when no fixed peer), last time
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            if bind is not None:  # no SO_REUSEADDR: a second user of the port must fail, not share it
                self.sock.bind(bind)
            if peer is not None:
                self.peer = (socket.gethostbyname(peer[0]), peer[1])
                if bind is None and ipaddress.ip_address(self.peer[0]).is_loopback:
                    self.sock.bind(("127.0.0.1", 0))  # a loopback peer: the socket stays on loopback too
        except OSError as exc:
            self.sock.close()
            raise ValueError(f"{url}: {exc.strerror or exc}") from None
        self.sock.setblocking(False)

    @property
    def address(self) -> tuple[str, int]:
        host, port = self.sock.getsockname()[:2]  # (host, port[, flowinfo, scope_id])
        return str(host), int(port)

    def _send_internal(self, data: bytes) -> None:
        targets = [self.peer] if self.peer is not None else list(self.peers)
        if not targets:
            raise NoPeer("no peer yet")
        for addr in targets:
            try:
                self.sock.sendto(data, addr)
            except ConnectionRefusedError:  # an ICMP "port unreachable" for an earlier datagram
                self.stats.refused += 1  # (nobody listens there yet): counted, not a fault, and
                self.sock.sendto(data, addr)  # this datagram still goes

    def _recv_internal(self, timeout_s: float, max_bytes: int) -> bytes | None:
        if timeout_s > 0:
            ready, _, _ = select.select([self.sock], [], [], timeout_s)
            if not ready:
                return None
        while True:
            try:
                data, addr = self.sock.recvfrom(65535)
            except BlockingIOError:
                return None
            except ConnectionRefusedError:  # ICMP: nobody listens at the peer address (yet)
                self.stats.refused += 1
                continue
            if self.peer is None:
                self._heard((addr[0], addr[1]))
            return data

    def _heard(self, addr: tuple[str, int]) -> None:
        now = self.last_poll_s or 0.0
        self.peers.pop(addr, None)
        self.peers[addr] = now
        for a in [a for a, t in self.peers.items() if now - t > self.peer_timeout_s]:
            del self.peers[a]
        while len(self.peers) > self.max_peers:
            del self.peers[next(iter(self.peers))]  # the least recently heard

    def _close_internal(self) -> None:
        self.sock.close()


class SerialLike(Protocol):
    """What :class:`SerialPort` uses of a pyserial ``Serial`` (or a test's stand-in)."""

    timeout: float | None

    @property
    def in_waiting(self) -> int: ...

    def read(self, size: int = 1) -> bytes: ...

    def write(self, data: bytes, /) -> int | None: ...

    def close(self) -> None: ...


class SerialPort(BytePort):
    """A serial line through pyserial: a byte stream, reopened after it is lost."""

    packetized = False

    def __init__(self, device: str, baud: int, ser: SerialLike | None = None, reopen_s: float = 2.0,
                 max_send_bytes: int = 65536) -> None:
        """Open ``device`` (a path or a pyserial URL such as ``loop://``) at ``baud``, or use
        ``ser``, an already open pyserial-like object; ValueError if it cannot be opened."""
        super().__init__(f"serial:{device}@{baud}", max_send_bytes, reopen_s)
        self.device, self.baud = device, baud
        if ser is None:
            try:
                ser = self._open()
            except OSError as exc:
                raise ValueError(f"serial:{device}: {exc}") from None
        self.ser = ser

    def _open(self) -> SerialLike:
        import serial  # pyserial; imported here so the other ports do not need it

        try:
            return serial.serial_for_url(self.device, baudrate=self.baud, timeout=0, write_timeout=0)
        except (serial.SerialException, ValueError) as exc:
            raise OSError(str(exc)) from None

    def _reopen_internal(self) -> None:
        self.ser = self._open()

    def _send_internal(self, data: bytes) -> None:
        try:
            n = self.ser.write(data)
        except Exception as exc:  # noqa: BLE001 - pyserial raises several types on unplug
            if type(exc).__name__ == "SerialTimeoutException":  # the modem's buffer is full
                raise OSError("output buffer full") from None
            raise PortLost(f"write: {exc}") from None
        if n is not None and n != len(data):
            raise OSError(f"short write, {n} of {len(data)} bytes")

    def _recv_internal(self, timeout_s: float, max_bytes: int) -> bytes | None:
        try:
            if timeout_s > 0:
                self.ser.timeout = timeout_s
                data = bytes(self.ser.read(1))
                self.ser.timeout = 0
                data += bytes(self.ser.read(max(0, min(max_bytes, self.ser.in_waiting) - 1)))
            else:
                data = bytes(self.ser.read(max_bytes))  # timeout=0: what is there, at once
        except Exception as exc:  # noqa: BLE001 - pyserial raises several types on unplug
            raise PortLost(f"read: {exc}") from None
        return data or None

    def _close_internal(self) -> None:
        self.ser.close()
