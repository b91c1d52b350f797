"""The lockstep bench's in-process CAN bus (fsw/drivers/can_inproc.py; issue 15 item 2)."""

from __future__ import annotations

import can
import pytest

from fsw.drivers.can_inproc import InprocBus, open_bus


def test_delivers_copies_to_every_other_bus_and_shares_virtual_channels() -> None:
    a = open_bus(interface="virtual", channel="inproc-test-1")
    assert isinstance(a, InprocBus)
    b = can.Bus(interface="virtual", channel="inproc-test-1")  # a plain python-can virtual bus
    try:
        buf = bytearray(b"\x01\x02\x03")
        sent = can.Message(arbitration_id=0x123, data=buf, is_extended_id=False)
        a.send(sent)
        buf[0] = 0xFF  # the sender reuses its buffer: the queued frame keeps what was sent
        sent.data[1] = 0xEE
        got = b.recv(timeout=0.0)
        assert got is not None and got is not sent
        assert got.arbitration_id == 0x123 and bytes(got.data) == b"\x01\x02\x03"
        assert got.is_rx and not got.is_extended_id and got.channel == "inproc-test-1"
        assert a.recv(timeout=0.0) is None  # no echo of its own frame unless asked
        b.send(can.Message(arbitration_id=0x7, data=b"\x09"))
        back = a.recv(timeout=0.0)
        assert back is not None and bytes(back.data) == b"\x09"
    finally:
        a.shutdown()
        b.shutdown()


def test_full_receiver_queue_is_a_can_error() -> None:
    a = InprocBus(channel="inproc-test-2")
    b = can.Bus(interface="virtual", channel="inproc-test-2", rx_queue_size=1)
    try:
        a.send(can.Message(arbitration_id=1, data=b""))
        with pytest.raises(can.CanOperationError):
            a.send(can.Message(arbitration_id=2, data=b""), timeout=0.0)
    finally:
        a.shutdown()
        b.shutdown()


def test_poll_applies_the_filters_and_keeps_the_order() -> None:
    a = InprocBus(channel="inproc-test-3")
    b = can.Bus(interface="virtual", channel="inproc-test-3")
    try:
        a.set_filters([{"can_id": 0x100, "can_mask": 0x700}])
        for i in (0x101, 0x200, 0x102):
            b.send(can.Message(arbitration_id=i, data=b"\x00"))
        got = [a.recv(timeout=0.0), a.recv(timeout=0.0), a.recv(timeout=0.0)]
        assert [m.arbitration_id if m else None for m in got] == [0x101, 0x102, None]
    finally:
        a.shutdown()
        b.shutdown()
