"""python-can ``udp_multicast`` pinned to a named interface (issue 31, item 1): the group is
joined on that interface only and frames go out on it (here ``lo``)."""

from __future__ import annotations

import random
import socket
from pathlib import Path

import can
import pytest

from fsw.drivers.can_inproc import open_bus

pytestmark = pytest.mark.req("31.1")
GROUP = "239.74.163.77"  # not the default group: concurrent runs elsewhere on this machine use that one


def igmp_devices(group: str) -> list[str]:
    """The interfaces ``/proc/net/igmp`` lists ``group`` under."""
    hexed = socket.inet_aton(group)[::-1].hex().upper()
    devices, dev = [], ""
    for line in Path("/proc/net/igmp").read_text().splitlines()[1:]:
        if not line.startswith("\t"):
            dev = line.split()[1]
        elif line.split()[0] == hexed:
            devices.append(dev)
    return devices


def test_pinned_to_lo_frames_flow_and_the_group_is_joined_on_lo_only() -> None:
    kw = {"interface": "udp_multicast", "channel": GROUP, "port": random.randint(40000, 60000), "fd": False,
          "interface_name": "lo"}
    a, b = open_bus(**kw), open_bus(**kw)
    try:
        assert "on lo" in a.channel_info and igmp_devices(GROUP) == ["lo"]
        a.send(can.Message(arbitration_id=0x123, data=b"\x01\x02", is_extended_id=False))
        got = b.recv(timeout=2.0)
        assert got is not None and got.arbitration_id == 0x123 and bytes(got.data) == b"\x01\x02"
    finally:
        a.shutdown()
        b.shutdown()
    assert igmp_devices(GROUP) == []


def test_an_unknown_interface_is_refused_by_name() -> None:
    with pytest.raises(can.CanInitializationError, match="no network interface 'nonexistent0'"):
        open_bus(interface="udp_multicast", channel=GROUP, port=43113, fd=False, interface_name="nonexistent0")
