"""The ground link's byte transport: UDP (``udpin`` / ``udpout``) or a serial radio.

A :class:`~fsw.drivers.byte_port.BytePort` opened from a pymavlink-style URL. The task reads
it with ``recv_upto(max_bytes, now)`` (a list of chunks: one per UDP datagram,
``packetized = True``, a frame never spans two; chunks of the serial byte stream) and sends
with ``send(packet, now)`` (the task joins an activation's frames into one packet, as
ArduPilot does; pymavlink, MAVProxy and QGroundControl parse several frames a datagram).
Errors never raise: they set fault bits and ``fault_reason`` (one line), are counted, and a
lost serial port is reopened every ``reopen_s``. URLs:

* ``udpin:HOST:PORT`` - bind and answer every peer heard from in the last 30 s
  (e.g. MAVProxy ``--master=udpout:ROVER:PORT``);
* ``udpout:HOST:PORT`` - send to a ground station listening there (MAVProxy
  ``--master=udpin:0.0.0.0:PORT``, QGroundControl's default 14550) and accept its replies;
* ``serial:DEVICE`` at ``baud``.
"""

from __future__ import annotations

from fsw.drivers.byte_port import BytePort, SerialPort, UdpPort


class TransportError(ValueError):
    """The URL cannot be opened (bad form, port in use, no such device)."""


def open_transport(url: str, baud: int = 57600) -> BytePort:
    """Open a transport from its URL; raises :class:`TransportError` with the reason."""
    kind, _, rest = url.partition(":")
    try:
        if kind in ("udpin", "udpout"):
            host, _, port = rest.rpartition(":")
            if not host or not port.isdigit() or not 0 <= int(port) < 65536:
                raise ValueError(f"{url}: expected {kind}:HOST:PORT")
            addr = (host, int(port))
            return UdpPort(url, addr, None) if kind == "udpin" else UdpPort(url, None, addr)
        if kind == "serial" and rest:
            return SerialPort(rest, baud)
    except ValueError as exc:
        raise TransportError(str(exc)) from None
    raise TransportError(f"{url}: expected udpin:HOST:PORT, udpout:HOST:PORT or serial:DEVICE")
