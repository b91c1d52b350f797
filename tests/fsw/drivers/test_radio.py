"""Radio transports and the channel model (issue 6, items 6 and 7)."""

from __future__ import annotations

import time

import numpy as np
import pytest

from fsw.comm.link import LinkConfig
from fsw.comm.link_receiver import LinkReceiver
from fsw.comm.link_sender import LinkSender, SenderState
from fsw.drivers.byte_port import BytePort, InProcPort
from fsw.drivers.radio import MAX_DATAGRAM, SerialRadio, open_radio
from hil_sim.link.radio_channel import ChannelPort, RadioChannel, RadioChannelConfig


def _transfer_real_time(a: BytePort, b: BytePort, data: bytes, timeout_s: float = 10.0) -> bytes | None:
    """Run sender on ``a`` and receiver on ``b`` on the wall clock until delivery."""
    cfg = LinkConfig(rate_bps=2e6, segment_bytes=512, status_period_s=0.05,
                     min_status_interval_s=0.01, ping_period_s=0.05)
    tx, rx = LinkSender(cfg, session=77), LinkReceiver(cfg)
    t0 = time.monotonic()
    tx.start(9, data, 0.0)
    got = None
    while time.monotonic() - t0 < timeout_s:
        now = time.monotonic() - t0
        for pkt in tx.poll(now):
            a.send(pkt, now)
        for port, end in ((b, rx), (a, tx)):
            d = port.recv(0.002, now)
            while d is not None:
                end.receive(d, now)
                d = port.recv(0.0, now)
        for pkt in rx.poll(now):
            b.send(pkt, now)
        got = got or rx.take_map()
        if got and tx.state is SenderState.DONE:
            break
    return got[1] if got else None


def test_inproc_pair_carries_a_map():
    """Issue 6, item 6: in-process endpoints (lockstep / tests)."""
    data = np.random.default_rng(0).bytes(20000)
    a, b = InProcPort.pair("t-inproc")
    with a, b:
        assert _transfer_real_time(a, b, data) == data
    ends = [InProcPort("t3"), InProcPort("t3")]
    with pytest.raises(ValueError, match="already has two ends"):
        InProcPort("t3")
    for e in ends:
        e.close()


def test_udp_loopback_carries_a_map():
    """Issue 6, item 6: UDP on loopback (udp://HOST:PORT), reply-to-sender on the Cliff-bot."""
    data = np.random.default_rng(1).bytes(30000)
    b = open_radio("udp://127.0.0.1:0")
    host, port = b.address
    a = open_radio("udp://127.0.0.1:0", peer=f"udp://{host}:{port}")
    with a, b:
        assert _transfer_real_time(a, b, data) == data
        assert a.stats.tx_packets > 60 and b.stats.rx_packets > 60


def test_serial_modem_framing_resyncs_after_garbage():
    """Issue 6, item 6: COBS framing over pyserial; line noise is skipped, not fatal."""
    import serial

    # loop:// simulates the line's time, so it needs a write timeout; a real port runs non-blocking
    r = SerialRadio("loop://", 115200, ser=serial.serial_for_url("loop://", baudrate=115200, timeout=0))
    with r:
        r.ser.write(b"\x13\x37garbage\x00")  # not a valid COBS frame (decodes to junk or fails)
        r.ser.write(b"\x05ab\x00")  # truncated COBS block: a framing error
        r.send(b"hello\x00world")
        r.send(b"")
        r.send(bytes(range(256)) * 3)
        got = [r.recv(0.1) for _ in range(5)]
    assert b"hello\x00world" in got and bytes(range(256)) * 3 in got
    assert r.stats.rx_errors >= 1


def test_serial_modem_carries_a_map_over_a_pty():
    """Issue 6, item 6: the same protocol over a serial radio modem (pty pair)."""
    import os

    master, slave = os.openpty()
    a = SerialRadio(os.ttyname(slave), 115200)
    b = SerialRadio("pty-master", 115200, ser=_FdSerial(master))
    data = np.random.default_rng(2).bytes(5000)
    try:
        assert _transfer_real_time(a, b, data) == data
    finally:
        a.close()
        os.close(master)
        os.close(slave)


class _FdSerial:
    """Minimal pyserial-like wrapper of a pty master fd (read in chunks)."""

    def __init__(self, fd: int) -> None:
        import os

        self.fd, self.os, self.timeout = fd, os, 0.0

    @property
    def in_waiting(self) -> int:
        return 4096

    def read(self, n: int) -> bytes:
        import select

        r, _, _ = select.select([self.fd], [], [], self.timeout or 0)
        return self.os.read(self.fd, n) if r else b""

    def write(self, data: bytes) -> None:
        self.os.write(self.fd, data)

    def close(self) -> None:
        pass


def test_open_radio_rejects_bad_urls_and_send_faults_do_not_raise():
    """Issue 6, item 6: bad URLs are a clear ValueError; a failed send is a fault, not a crash."""
    for url in ("tcp://x:1", "udp://nohostport", "udp://127.0.0.1:notaport", "inproc://", "serial:"):
        with pytest.raises(ValueError):
            open_radio(url)
    u = open_radio("udp://127.0.0.1:0")  # no peer yet: not sent, counted, not a fault
    assert u.send(b"x") is False and u.stats.no_peer == 1 and not u.fault
    assert u.send(bytes(MAX_DATAGRAM + 1), 5.0) is False and u.has(u.FAULTS["TX_ERROR"])
    assert u.drain_events()[0][0] == "TX_ERROR" and u.stats.tx_errors == 1
    assert u.fault_reason is not None and "over 8192" in u.fault_reason
    u.send(b"x", 5.0 + u.error_hold_s)  # the held bit clears after error_hold_s without a new error
    assert not u.has(u.FAULTS["TX_ERROR"])
    u.close()
    assert u.send(b"x") is False and u.recv() is None and u.has(u.FAULTS["CLOSED"])


def test_channel_model_statistics_and_determinism():
    """Issue 6, item 7: seeded loss, BER, duplication, reordering, rate and latency."""
    cfg = RadioChannelConfig(loss=0.2, ber=1e-4, duplicate=0.1, reorder=0.1, latency_s=0.3)
    runs = []
    for _ in range(2):
        ch = RadioChannel(cfg, seed=11)
        for i in range(2000):
            ch.send("a", bytes([i % 256]) * 100, i * 0.1)
        runs.append(ch.receive("b", 1e6))
        st = ch.stats("a")
    assert runs[0] == runs[1]
    assert st.lost == pytest.approx(400, rel=0.2)
    assert st.duplicated == pytest.approx(160, rel=0.3)
    assert st.corrupted == pytest.approx(0.8 * 1.1 * 2000 * (1 - (1 - 1e-4) ** 800), rel=0.25)
    order = [r[0] for r in runs[0]]
    assert order != sorted(order, key=lambda b: b)  # something was reordered


def test_channel_serialises_at_the_bit_rate_and_honours_outages():
    """Issue 6, item 7: 9600 bit/s default, latency added, outage drops."""
    ch = RadioChannel(RadioChannelConfig(latency_s=0.1, outages=((2.0, 1.0),)), seed=0)
    for _ in range(3):
        ch.send("a", b"x" * 120, 0.0)  # 0.1 s on the air each
    assert ch.receive("b", 0.2) == [b"x" * 120]
    assert ch.receive("b", 0.41) == [b"x" * 120] * 2
    ch.send("b", b"y" * 12, 2.5)
    ch.send("b", b"z" * 12, 3.5)
    assert ch.receive("a", 10.0) == [b"z" * 12]
    assert ch.stats("b").outage_drops == 1


def test_channel_port_is_a_radio_port():
    """Issue 6, item 6: the channel model behind the same RadioPort interface."""
    clock = [0.0]
    ch = RadioChannel(RadioChannelConfig(rate_bps=1e6, latency_s=0.0), seed=0)
    a, b = ChannelPort(ch, "a", lambda: clock[0]), ChannelPort(ch, "b", lambda: clock[0])
    assert a.send(b"ping")
    clock[0] = 1.0
    assert b.recv() == b"ping" and b.recv() is None
