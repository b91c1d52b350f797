"""The loopback checker the multi-process tests use (issue 31, item 3) finds what it must."""

from __future__ import annotations

import os
import socket

import pytest
from loopback import off_machine_sockets

pytestmark = pytest.mark.req("31.3")


def test_a_socket_open_to_the_network_is_reported_a_loopback_one_not() -> None:
    pid = os.getpid()
    udp = socket.SOCK_DGRAM
    with socket.socket(socket.AF_INET, udp) as lo, socket.socket(socket.AF_INET, udp) as any_:
        lo.bind(("127.0.0.1", 0))
        lo.connect(("127.0.0.1", 9))
        assert not [b for b in off_machine_sockets([pid]) if f"fd {lo.fileno()}:" in b]
        any_.sendto(b"x", ("127.0.0.1", 9))  # sendto binds an unbound socket to 0.0.0.0: every interface
        assert [b for b in off_machine_sockets([pid]) if f"fd {any_.fileno()}:" in b] == [
            f"pid {pid} fd {any_.fileno()}: bound to 0.0.0.0:{any_.getsockname()[1]}"]
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as out:
        try:
            out.connect(("192.0.2.1", 9))  # TEST-NET-1: connecting sends nothing
        except OSError:  # no route (a namespace with only lo): no such socket can exist
            return
        assert any("peer 192.0.2.1:9" in b for b in off_machine_sockets([pid]))
