"""Issue 7, item 5: transports from config - UDP udpin/udpout on loopback and a serial line
(a pty pair); faults are flags and events, never exceptions."""

from __future__ import annotations

import os
import socket
import time
from pathlib import Path

import ground_demo
import pytest

from fsw.drivers.byte_port import SerialPort, UdpPort
from fsw.drivers.mavlink_transport import TransportError, open_transport


def _recv(t, n: int = 1, timeout_s: float = 2.0, nbytes: int = 0) -> list[bytes]:  # type: ignore[no-untyped-def]
    """``n`` chunks (datagrams), or chunks until ``nbytes`` bytes (a byte stream)."""
    got: list[bytes] = []
    deadline = time.monotonic() + timeout_s
    while (len(got) < n or sum(map(len, got)) < nbytes) and time.monotonic() < deadline:
        got += t.recv_upto(65536, time.monotonic())
        time.sleep(0.005)
    return got


def test_udpin_and_udpout_back_to_back() -> None:
    """Issue 7, item 5: udpin answers the peers it heard; udpout sends to its address and
    accepts replies; one datagram per frame."""
    server = open_transport("udpin:127.0.0.1:0")
    assert isinstance(server, UdpPort) and server.packetized
    assert server.send(b"nobody yet", 0.0) is False  # no peer heard: nothing sent, no exception
    client = open_transport(f"udpout:127.0.0.1:{server.address[1]}")
    assert isinstance(client, UdpPort) and client.address[0] == "127.0.0.1"  # issue 31: loopback peer, loopback socket
    assert client.send(b"\xfdhello", 0.0) and client.send(b"\xfdworld", 0.0)
    assert _recv(server, 2) == [b"\xfdhello", b"\xfdworld"]
    assert server.send(b"\xfdreply", 0.0)
    assert _recv(client) == [b"\xfdreply"]
    server.close()
    client.close()


def test_udpout_without_listener_and_bad_urls() -> None:
    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    probe.bind(("127.0.0.1", 0))
    port = probe.getsockname()[1]
    probe.close()
    t = open_transport(f"udpout:127.0.0.1:{port}")
    for _ in range(3):
        t.send(b"x", 0.0)
        t.recv_upto(100, 0.0)  # ICMP port unreachable comes back as ECONNREFUSED: counted, not raised
    t.close()
    for url in ("udp:1.2.3.4:5", "udpin:127.0.0.1:x", "serial:", "tcp:127.0.0.1:5760"):
        with pytest.raises(TransportError):
            open_transport(url)
    busy = open_transport("udpin:127.0.0.1:0")
    with pytest.raises(TransportError):  # port in use
        open_transport(f"udpin:127.0.0.1:{busy.address[1]}")
    busy.close()


def test_serial_over_pty() -> None:
    """Issue 7, item 5: a serial radio (a pty pair stands in) both ways; unplug -> fault."""
    master, slave = os.openpty()
    t = open_transport(f"serial:{os.ttyname(slave)}", 57600)
    assert isinstance(t, SerialPort) and not t.packetized
    os.write(master, b"\xfd\x01\x02\x03")
    assert b"".join(_recv(t, nbytes=4)) == b"\xfd\x01\x02\x03"
    assert t.send(b"\xfdabc", 0.0)
    assert os.read(master, 100) == b"\xfdabc"
    os.close(master)  # the radio goes away: a fault flag, no exception, reopen attempts later
    deadline = time.monotonic() + 2.0
    while t.fault_reason is None and time.monotonic() < deadline:
        t.recv_upto(100, 0.0)
        t.send(b"\xfdx", 0.0)
        time.sleep(0.01)
    assert t.fault_reason is not None and t.has(t.FAULTS["LOST"]) and t.recv_upto(100, 0.0) == []
    t.close()
    os.close(slave)
    with pytest.raises(TransportError):
        open_transport("serial:/dev/does-not-exist", 57600)


def test_task_survives_an_unopenable_link(key_file: Path, demo_kind: None) -> None:
    """A link that cannot be opened is a TRANSPORT_FAULT event; the task runs on (the .tlog
    still records the downlink)."""
    busy = open_transport("udpin:127.0.0.1:0")
    exe = ground_demo.build(ground_demo.config(f"udpin:127.0.0.1:{busy.address[1]}", str(key_file)))
    exe.run_lockstep(20)
    busy.close()
    assert exe.events.count("mavlink.TRANSPORT_FAULT") == 1
    assert exe.tasks["mavlink"].exceptions == 0 and exe.telemetry.get("mavlink.tx_frames") > 0
