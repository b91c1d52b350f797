"""python-can ``udp_multicast`` pinned to one named network interface.

python-can's ``udp_multicast`` joins its group on "any" interface and sends where the routing
table sends multicast (on a lab machine: the default route's interface, the lab network). This
bus is that interface with the interface named: the group is joined on it (``ip_mreqn`` with its
index) and sent on it (``IP_MULTICAST_IF``), hop limit 1. It is for a bench spread over machines
on purpose (``can_interface = "udp_multicast"`` with ``can_multicast_interface``, docs/hil.md);
one machine's processes use ``udp_hub``. IPv4 groups only. Frames, codec and timestamps are
python-can's.
"""

from __future__ import annotations

import socket
import struct
from typing import Any

import can
from can.bus import CanProtocol
from can.interfaces.udp_multicast import UdpMulticastBus
from can.interfaces.udp_multicast.bus import GeneralPurposeUdpMulticastBus


class _PinnedSocket(GeneralPurposeUdpMulticastBus):  # type: ignore[misc]
    """python-can's multicast socket, joined and sending on one interface."""

    def __init__(self, group: str, port: int, hop_limit: int, interface_name: str) -> None:
        try:
            self.ifindex = socket.if_nametoindex(interface_name)
        except OSError:
            raise can.CanInitializationError(f"udp_multicast: no network interface {interface_name!r}") from None
        super().__init__(group, port, hop_limit)

    def _create_socket(self, address_family: socket.AddressFamily) -> socket.socket:
        if address_family != socket.AF_INET:
            raise OSError("udp_multicast on a named interface: IPv4 groups only")
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            mreqn = struct.pack("4s4si", socket.inet_aton(self.group), socket.inet_aton("0.0.0.0"), self.ifindex)
            sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, struct.pack("@I", self.hop_limit))
            sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, mreqn)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
            sock.bind((self.group, self.port))  # only this group's datagrams, not every packet to the port
            sock.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP, mreqn)
        except OSError as exc:
            sock.close()
            raise can.CanInitializationError(f"udp_multicast {self.group}: {exc.strerror or exc}") from None
        self.timestamp_nanosecond = False  # the receive time comes from SIOCGSTAMP (python-can's fallback)
        return sock


class PinnedMulticastBus(UdpMulticastBus):  # type: ignore[misc]
    """``UdpMulticastBus(channel=GROUP, port=PORT, interface_name=IFACE)``: the group on IFACE only."""

    def __init__(self, channel: str = UdpMulticastBus.DEFAULT_GROUP_IPv4, port: int = 43113, hop_limit: int = 1,
                 fd: bool = False, *, interface_name: str, **kwargs: Any) -> None:
        # UdpMulticastBus.__init__ without its socket: that one would join the group on "any" interface
        self._multicast = _PinnedSocket(channel, port, hop_limit, interface_name)
        can.BusABC.__init__(self, channel, **kwargs)
        self._can_protocol = CanProtocol.CAN_FD if fd else CanProtocol.CAN_20
        self.channel_info = f"udp_multicast {channel}:{port} on {interface_name}"
