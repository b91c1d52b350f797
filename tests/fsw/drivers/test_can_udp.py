"""The ``udp_hub`` CAN interface and the bench's hub (issue 31, item 1).

Nodes are python-can buses opened by name (the entry point), the hub a thread on 127.0.0.1.
Waiting is on the hub's relay count, not on sleeps; loopback delivery is done when ``sendto``
returns.
"""

from __future__ import annotations

import socket
import time
from collections.abc import Iterator

import can
import pytest

from fsw.drivers import can_udp
from fsw.drivers.can_udp import FRAME, JOIN, LEAVE, MAGIC, UdpHubBus, parse_channel
from hil_sim.hw.can_hub import CanHub

pytestmark = pytest.mark.req("31.1")


def wait_for(pred, timeout_s: float = 60.0) -> None:  # type: ignore[no-untyped-def]
    """Until ``pred()`` holds: returns as soon as it does; the limit only ends a hang (a loaded
    machine may not run the hub's thread for seconds)."""
    deadline = time.monotonic() + timeout_s
    while not pred():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.001)


def msg(i: int, data: bytes = b"\x01\x02") -> can.Message:
    return can.Message(arbitration_id=i, data=data, is_extended_id=False)


@pytest.fixture
def hub() -> Iterator[CanHub]:
    with CanHub() as h:
        yield h


def nodes(hub: CanHub, n: int, **kw: object) -> list[can.BusABC]:
    buses = [can.Bus(interface="udp_hub", channel=hub.channel, **kw) for _ in range(n)]
    wait_for(lambda: len(hub.nodes) == n)
    return buses


def drain(bus: can.BusABC) -> list[can.Message]:
    out = []
    while (m := bus.recv(timeout=0.0)) is not None:
        out.append(m)
    return out


def test_entry_point_registers_the_interface() -> None:
    assert "udp_hub" in can.interfaces.VALID_INTERFACES
    with can.Bus(interface="udp_hub", channel="127.0.0.1:9") as bus:
        assert isinstance(bus, UdpHubBus) and bus.channel == "127.0.0.1:9"


def test_hub_and_nodes_stay_on_loopback_by_default(hub: CanHub) -> None:
    assert hub.address[0] == "127.0.0.1" and parse_channel(None) == ("127.0.0.1", 43113)
    (bus,) = nodes(hub, 1)
    assert bus._sock.getsockname()[0] == "127.0.0.1" and bus._sock.getpeername() == hub.address  # type: ignore[attr-defined]
    bus.shutdown()


def test_every_frame_reaches_every_other_node_once_in_order_never_its_sender(hub: CanHub) -> None:
    a, b, c = nodes(hub, 3)
    t0 = time.time()
    for i in range(100):  # a burst: the bench's busiest frame sends ~30
        a.send(msg(i, i.to_bytes(2, "big")))
    c.send(msg(0x55))
    wait_for(lambda: hub.frames == 101)
    got_b, got_c, got_a = drain(b), drain(c), drain(a)
    assert [int.from_bytes(m.data, "big") for m in got_b[:100]] == list(range(100))
    assert got_b[100].arbitration_id == 0x55
    assert len(got_c) == 100 and [m.arbitration_id for m in got_a] == [0x55]
    assert all(m.is_rx and t0 <= m.timestamp <= time.time() for m in got_b + got_c)
    for bus in (a, b, c):
        bus.shutdown()


def test_own_frames_echo_locally_when_asked(hub: CanHub) -> None:
    a, b = nodes(hub, 2, receive_own_messages=True)
    a.send(msg(1))
    wait_for(lambda: hub.frames == 1)
    own, other = drain(a), drain(b)
    assert [(m.arbitration_id, m.is_rx) for m in own] == [(1, False)]
    assert [(m.arbitration_id, m.is_rx) for m in other] == [(1, True)]
    a.shutdown()
    b.shutdown()


def test_filters_and_recv_timeout(hub: CanHub) -> None:
    a, b = nodes(hub, 2)
    b.set_filters([{"can_id": 0x10, "can_mask": 0x7FF, "extended": False}])
    a.send(msg(0x11))
    a.send(msg(0x10))
    wait_for(lambda: hub.frames == 2)
    assert b.recv(timeout=1.0).arbitration_id == 0x10  # type: ignore[union-attr]
    t0 = time.monotonic()
    assert b.recv(timeout=0.05) is None and time.monotonic() - t0 >= 0.05
    a.shutdown()
    b.shutdown()


def test_shutdown_leaves_the_hub_and_closes_the_bus(hub: CanHub) -> None:
    a, b = nodes(hub, 2)
    a.shutdown()
    wait_for(lambda: len(hub.nodes) == 1)
    with pytest.raises(can.CanOperationError):
        a.send(msg(1))
    with pytest.raises(can.CanOperationError):
        a.recv(timeout=0.0)
    a.shutdown()  # idempotent
    b.shutdown()


def test_no_hub_is_a_send_error_with_a_reason() -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]  # free once closed: nobody listens there
    with can.Bus(interface="udp_hub", channel=f"127.0.0.1:{port}") as bus:
        errors = []
        for _ in range(50):  # the join's ICMP "port unreachable" makes a later send fail
            try:
                bus.send(msg(1))
            except can.CanOperationError as exc:
                errors.append(str(exc))
            assert bus.recv(timeout=0.0) is None  # reading never raises for it
        assert errors and "no hub listening" in errors[0]


@pytest.mark.parametrize("channel", ["127.0.0.1:x", "127.0.0.1:0", "127.0.0.1:70000", ":43113"])
def test_bad_channel_is_refused_with_the_form(channel: str) -> None:
    with pytest.raises(ValueError, match="HOST:PORT"):
        can.Bus(interface="udp_hub", channel=channel)


def test_undecodable_datagram_is_an_error_and_the_next_frame_still_arrives(hub: CanHub) -> None:
    a, b = nodes(hub, 2)
    for bad in (FRAME + b"\xc1garbage", b"Zhello"):
        hub.sock.sendto(bad, b._sock.getsockname())  # type: ignore[attr-defined]
    a.send(msg(7))
    wait_for(lambda: hub.frames == 1)
    with pytest.raises(can.CanOperationError, match="undecodable"):
        b.recv(timeout=0.0)
    with pytest.raises(can.CanOperationError, match="unknown kind"):
        b.recv(timeout=0.0)
    assert b.recv(timeout=0.0).arbitration_id == 7  # type: ignore[union-attr]
    # a datagram from anyone but the hub never reaches a node (its socket is connected to the hub)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as stray:
        stray.sendto(FRAME + can_udp.pack_message(msg(9)), b._sock.getsockname())  # type: ignore[attr-defined]
    a.send(msg(8))
    wait_for(lambda: hub.frames == 2)
    assert [m.arbitration_id for m in drain(b)] == [8]
    a.shutdown()
    b.shutdown()


def test_nodes_rejoin_a_restarted_hub(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(can_udp, "KEEPALIVE_S", 0.0)  # every call re-joins: no waiting for the period
    first = CanHub().start()
    port = first.address[1]
    a, b = nodes(first, 2)
    first.close()
    with CanHub(port=port) as second:
        assert not second.nodes
        b.recv(timeout=0.0)  # a listening node re-joins from recv
        a.send(msg(3))
        wait_for(lambda: second.frames == 1)
        assert [m.arbitration_id for m in drain(b)] == [3]
    a.shutdown()
    b.shutdown()


class TestHubByHand:
    """The hub's bookkeeping, driven with datagrams and a stepped clock (no thread)."""

    def test_membership_expiry_and_bad_datagrams(self) -> None:
        hub = CanHub(expire_s=5.0, max_nodes=2)
        try:
            hub.handle(JOIN + MAGIC, ("127.0.0.1", 1), 0.0)
            hub.handle(JOIN + MAGIC, ("127.0.0.1", 2), 1.0)
            hub.handle(JOIN + MAGIC, ("127.0.0.1", 3), 1.0)  # beyond max_nodes: refused
            assert set(hub.nodes) == {("127.0.0.1", 1), ("127.0.0.1", 2)} and hub.refused_nodes == 1
            for bad in (b"", JOIN + b"other", b"Q" + MAGIC, FRAME):
                hub.handle(bad, ("127.0.0.1", 2), 2.0)
            assert hub.bad == 4 and len(hub.nodes) == 2
            hub.handle(JOIN + MAGIC, ("127.0.0.1", 2), 5.5)  # node 1 last heard at 0.0: gone
            assert set(hub.nodes) == {("127.0.0.1", 2)}
            hub.handle(LEAVE + MAGIC, ("127.0.0.1", 2), 6.0)
            assert not hub.nodes
        finally:
            hub.close()

    def test_a_second_hub_on_the_same_port_fails(self, hub: CanHub) -> None:
        with pytest.raises(OSError, match="CAN hub 127.0.0.1"):
            CanHub(port=hub.address[1])
