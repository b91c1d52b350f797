"""CAN between the bench's processes over UDP through a hub: python-can interface ``udp_hub``.

Registered with python-can by entry point (``[project.entry-points."can.interface"]`` in
``pyproject.toml``), so any python-can user opens it by name::

    can.Bus(interface="udp_hub", channel="127.0.0.1:43113")

``channel`` is the hub's ``HOST:PORT`` (``hil_sim.hw.can_hub``, run by ``safer-hil serve``);
the default is on 127.0.0.1, so the bus never leaves the machine unless a user names another
address. Each bus is one node: a UDP socket connected to the hub (the kernel then delivers only
the hub's datagrams to it). The hub relays every frame to every other node, never back to its
sender; ``receive_own_messages=True`` echoes a node's own frames locally, as python-can's
``virtual`` interface does. Received frames carry the receive time (``time.time()``).

Wire format, one datagram each: ``b"J" + MAGIC`` joins (and keeps the node alive: sent at
open, then at least every ``KEEPALIVE_S`` from ``send``/``recv``), ``b"L" + MAGIC`` leaves,
``b"F" + frame`` is a frame packed by python-can's own ``udp_multicast`` codec (msgpack). A
datagram that does not decode raises ``can.CanOperationError`` from ``recv`` (the drivers
count it as a bad frame). With no hub listening, ``send`` raises ``can.CanOperationError``
(no node acknowledges: like a real bus alone on its cable).
"""

from __future__ import annotations

import contextlib
import select
import socket
import time
from collections import deque
from typing import Any

import can
from can.bus import CanProtocol
from can.interfaces.udp_multicast.utils import pack_message, unpack_message
from can.typechecking import AutoDetectedConfig

MAGIC = b"SAFER-CAN-HUB/1"
JOIN, LEAVE, FRAME = b"J", b"L", b"F"
DEFAULT_HOST, DEFAULT_PORT = "127.0.0.1", 43113
KEEPALIVE_S = 1.0  # a node re-joins this often, so a restarted hub learns it within a second
RCVBUF_BYTES = 1 << 22  # frames queued while a process is busy (the kernel caps it at net.core.rmem_max)
MAX_DATAGRAM = 2048


def parse_channel(channel: Any) -> tuple[str, int]:
    """``"HOST:PORT"`` (or ``"HOST"``: the default port) -> (host, port); ValueError otherwise."""
    text = DEFAULT_HOST if channel in (None, "") else str(channel)
    host, sep, port = text.rpartition(":")
    if not sep:
        host, port = text, str(DEFAULT_PORT)
    if not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ValueError(f"udp_hub channel {text!r}: expected HOST:PORT, e.g. {DEFAULT_HOST}:{DEFAULT_PORT}")
    return host, int(port)


class UdpHubBus(can.BusABC):  # type: ignore[misc]
    """One node on a ``udp_hub`` CAN bus (see the module docstring)."""

    def __init__(self, channel: Any = None, receive_own_messages: bool = False, fd: bool = False,
                 **kwargs: Any) -> None:
        self.hub = parse_channel(channel)
        self.channel = f"{self.hub[0]}:{self.hub[1]}"
        super().__init__(channel=self.channel, **kwargs)
        self.channel_info = f"udp_hub {self.channel}"
        self._can_protocol = CanProtocol.CAN_FD if fd else CanProtocol.CAN_20
        self.receive_own_messages = receive_own_messages
        self.frames_sent = 0
        self._own: deque[can.Message] = deque()
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RCVBUF_BYTES)
            self._sock.connect(self.hub)
        except OSError as exc:
            self._sock.close()
            raise can.CanInitializationError(f"udp_hub {self.channel_info}: {exc.strerror or exc}") from None
        self._sock.setblocking(False)
        self._t_join = -1e9
        self._keepalive()

    # -- python-can's interface ------------------------------------------------------------------
    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self._check_if_open()
        if msg.is_fd and self._can_protocol is not CanProtocol.CAN_FD:
            raise can.CanOperationError("cannot send a CAN FD frame on a bus opened with fd=False")
        self._keepalive()
        try:
            self._sock.send(FRAME + pack_message(msg))
        except ConnectionRefusedError:
            raise can.CanOperationError(f"no hub listening at {self.channel} (is safer-hil serve running?)") from None
        except OSError as exc:
            raise can.CanOperationError(f"udp_hub send: {exc.strerror or exc}") from None
        self.frames_sent += 1
        if self.receive_own_messages:
            self._own.append(can.Message(
                timestamp=time.time(), arbitration_id=msg.arbitration_id, is_extended_id=msg.is_extended_id,
                is_remote_frame=msg.is_remote_frame, is_error_frame=msg.is_error_frame, channel=self.channel,
                dlc=msg.dlc, data=bytes(msg.data), is_fd=msg.is_fd, is_rx=False,
                bitrate_switch=msg.bitrate_switch, error_state_indicator=msg.error_state_indicator,
            ))

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        self._check_if_open()
        if self._own:
            return self._own.popleft(), False
        self._keepalive()
        data = self._read(timeout)
        if data is None:
            return None, False
        if data[:1] != FRAME:
            raise can.CanOperationError(f"udp_hub: datagram of unknown kind {data[:1]!r} ({len(data)} bytes)")
        try:
            msg = unpack_message(data[1:], replace={"timestamp": time.time(), "is_rx": True,
                                                    "channel": self.channel}, check=True)
        except Exception as exc:  # noqa: BLE001 - msgpack and Message raise several kinds
            raise can.CanOperationError(f"udp_hub: undecodable frame ({type(exc).__name__}: {exc})") from None
        if msg.is_fd and self._can_protocol is not CanProtocol.CAN_FD:
            return None, False
        return msg, False

    def fileno(self) -> int:
        return self._sock.fileno()

    def shutdown(self) -> None:
        if self._is_shutdown:
            return
        super().shutdown()
        with contextlib.suppress(OSError):  # no hub: nobody to tell
            self._sock.send(LEAVE + MAGIC)
        self._sock.close()

    @staticmethod
    def _detect_available_configs() -> list[AutoDetectedConfig]:
        return [{"interface": "udp_hub", "channel": f"{DEFAULT_HOST}:{DEFAULT_PORT}"}]

    # -- internals ---------------------------------------------------------------------------------
    def _check_if_open(self) -> None:
        if self._is_shutdown:
            raise can.CanOperationError(f"{self.channel_info}: the bus is shut down")

    def _keepalive(self) -> None:
        now = time.monotonic()
        if now - self._t_join < KEEPALIVE_S:
            return
        self._t_join = now
        with contextlib.suppress(OSError):  # no hub yet: the next keepalive tries again
            self._sock.send(JOIN + MAGIC)

    def _read(self, timeout: float | None) -> bytes | None:
        """One datagram from the hub, waiting up to ``timeout`` (in slices that keep the node
        alive); None when nothing came."""
        deadline = None if timeout is None else time.monotonic() + max(0.0, timeout)
        while True:
            try:
                return self._sock.recv(MAX_DATAGRAM)
            except BlockingIOError:
                pass
            except ConnectionRefusedError:
                continue  # an earlier datagram found no hub: send reports that; read on
            left = KEEPALIVE_S if deadline is None else min(KEEPALIVE_S, deadline - time.monotonic())
            if left <= 0:
                return None
            select.select([self._sock], [], [], left)
            self._keepalive()
