"""The ground link's byte transport: UDP (``udpin`` / ``udpout``) or a serial radio.

One device, no protocol: non-blocking ``recv`` of at most ``max_bytes`` as a list of chunks
(one per UDP datagram, ``packetized = True``: a frame never spans two; one chunk of the
serial byte stream) and ``send`` of one frame (one UDP datagram per MAVLink frame, as
MAVProxy and QGroundControl expect). Errors
never raise: they set ``fault`` (a one-line reason), are counted, and the serial port is
reopened after ``reopen_s``. URLs follow pymavlink's spelling:

* ``udpin:HOST:PORT`` - bind and answer every peer heard from in the last ``peer_timeout_s``
  (e.g. MAVProxy ``--master=udpout:ROVER:PORT``);
* ``udpout:HOST:PORT`` - send to a ground station listening there (MAVProxy
  ``--master=udpin:0.0.0.0:PORT``, QGroundControl's default 14550) and accept its replies;
* ``serial:DEVICE`` at ``baud``.
"""

from __future__ import annotations

import contextlib
import errno
import socket
from typing import Protocol

UDP_MAX = 65535


class Transport(Protocol):
    packetized: bool
    fault: str | None
    tx_frames: int
    tx_errors: int
    rx_bytes: int

    def recv(self, max_bytes: int, now_s: float) -> list[bytes]: ...
    def send(self, frame: bytes, now_s: float) -> bool: ...
    def close(self) -> None: ...


class TransportError(ValueError):
    """The URL cannot be opened (bad form, port in use, no such device)."""


class UdpTransport:
    packetized = True

    def __init__(self, mode: str, host: str, port: int, peer_timeout_s: float = 30.0, max_peers: int = 8) -> None:
        self.mode, self.addr = mode, (host, port)
        self.peer_timeout_s, self.max_peers = peer_timeout_s, max_peers
        self.peers: dict[tuple[str, int], float] = {}
        self.fault: str | None = None
        self.tx_frames = self.tx_errors = self.rx_bytes = self.refused = 0
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            if mode == "udpin":  # no SO_REUSEADDR: a second rover on the port must fail, not share it
                self.sock.bind(self.addr)
            else:
                self.addr = (socket.gethostbyname(host), port)
        except OSError as exc:
            self.sock.close()
            raise TransportError(f"{mode}:{host}:{port}: {exc.strerror or exc}") from None
        self.sock.setblocking(False)

    @property
    def local_port(self) -> int:
        return int(self.sock.getsockname()[1])

    def recv(self, max_bytes: int, now_s: float) -> list[bytes]:
        chunks: list[bytes] = []
        n = 0
        while n < max_bytes:
            try:
                data, addr = self.sock.recvfrom(UDP_MAX)
            except BlockingIOError:
                break
            except ConnectionRefusedError:  # ICMP: nobody listens at the udpout address (yet)
                self.refused += 1
                continue
            except OSError as exc:
                self.fault = f"recv: {exc.strerror or exc}"
                break
            if self.mode == "udpin":
                self._heard(addr, now_s)
            chunks.append(data)
            n += len(data)
        self.rx_bytes += n
        return chunks

    def _heard(self, addr: tuple[str, int], now: float) -> None:
        self.peers[addr] = now
        for a in [a for a, t in self.peers.items() if now - t > self.peer_timeout_s]:
            del self.peers[a]
        while len(self.peers) > self.max_peers:
            del self.peers[min(self.peers, key=self.peers.__getitem__)]

    def send(self, frame: bytes, now_s: float) -> bool:
        targets = list(self.peers) if self.mode == "udpin" else [self.addr]
        ok = bool(targets)
        for addr in targets:
            try:
                self.sock.sendto(frame, addr)
            except (BlockingIOError, ConnectionRefusedError):
                ok = False
                self.tx_errors += 1
            except OSError as exc:
                ok = False
                self.tx_errors += 1
                if exc.errno not in (errno.ENOBUFS, errno.EAGAIN):
                    self.fault = f"send: {exc.strerror or exc}"
        if ok:
            self.tx_frames += 1
            self.fault = None
        return ok

    def close(self) -> None:
        self.sock.close()


class SerialTransport:
    packetized = False

    def __init__(self, device: str, baud: int, reopen_s: float = 2.0) -> None:
        self.device, self.baud, self.reopen_s = device, baud, reopen_s
        self.fault: str | None = None
        self.tx_frames = self.tx_errors = self.rx_bytes = self.reopens = 0
        self._next_open = 0.0
        self.port = None
        if not self._open(0.0):
            raise TransportError(f"serial:{device}: {self.fault}")

    def _open(self, now_s: float) -> bool:
        import serial

        try:
            self.port = serial.serial_for_url(self.device, baudrate=self.baud, timeout=0, write_timeout=0)
        except (serial.SerialException, OSError, ValueError) as exc:
            self.port, self.fault = None, f"open: {exc}"
            self._next_open = now_s + self.reopen_s
            return False
        self.fault = None
        return True

    def _lost(self, what: str, exc: Exception, now_s: float) -> None:
        self.fault = f"{what}: {exc}"
        if self.port is not None:
            with contextlib.suppress(Exception):  # closing a dead port
                self.port.close()
        self.port = None
        self._next_open = now_s + self.reopen_s

    def recv(self, max_bytes: int, now_s: float) -> list[bytes]:
        if self.port is None:
            if now_s < self._next_open or not self._open(now_s):
                return []
            self.reopens += 1
        assert self.port is not None
        try:
            data = bytes(self.port.read(max_bytes))  # timeout=0: what is there, at once
        except Exception as exc:  # noqa: BLE001 - pyserial raises several types on unplug
            self._lost("read", exc, now_s)
            return []
        self.rx_bytes += len(data)
        return [data] if data else []

    def send(self, frame: bytes, now_s: float) -> bool:
        if self.port is None:
            self.tx_errors += 1
            return False
        try:
            n = self.port.write(frame)
        except Exception as exc:  # noqa: BLE001 - a full radio buffer (write timeout) or an unplug
            if type(exc).__name__ == "SerialTimeoutException":
                self.tx_errors += 1
                return False
            self._lost("write", exc, now_s)
            self.tx_errors += 1
            return False
        if n is not None and n != len(frame):
            self.tx_errors += 1
            return False
        self.tx_frames += 1
        return True

    def close(self) -> None:
        if self.port is not None:
            self.port.close()


def open_transport(url: str, baud: int = 57600) -> UdpTransport | SerialTransport:
    """Open a transport from its URL; raises :class:`TransportError` with the reason."""
    kind, _, rest = url.partition(":")
    if kind in ("udpin", "udpout"):
        host, _, port = rest.rpartition(":")
        if not host or not port.isdigit() or not 0 <= int(port) < 65536:
            raise TransportError(f"{url}: expected {kind}:HOST:PORT")
        return UdpTransport(kind, host, int(port))
    if kind == "serial" and rest:
        return SerialTransport(rest, baud)
    raise TransportError(f"{url}: expected udpin:HOST:PORT, udpout:HOST:PORT or serial:DEVICE")
