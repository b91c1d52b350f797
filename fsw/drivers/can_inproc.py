"""The in-process CAN bus of the lockstep bench (``can_interface = "virtual"``), without
python-can's deep copy of every message.

python-can's ``virtual`` interface ``copy.deepcopy``s each sent message once per receiver:
about 20 us a frame, a third of the motor task's foreground on the bench (issue 15). This bus
is that interface with two changes: a poll (``recv(timeout=0)``) skips the timed wait loop,
and each receiver gets a new ``can.Message`` built from the
sent one's fields, its payload copied as bytes (so a sender that reuses its buffer cannot
change a queued frame). Channels, queues, ordering, own-message echo and the queue-full
error are python-can's, so it shares channels with plain ``virtual`` buses (the bench's
emulated hardware). On the rover the bus is ``socketcan``: the kernel copies the frame.
"""

from __future__ import annotations

import queue
import time
from typing import Any

import can
from can.interfaces.virtual import VirtualBus


class InprocBus(VirtualBus):  # type: ignore[misc]
    """python-can's virtual bus with a shallow, payload-copying send."""

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self._check_if_open()
        timestamp = msg.timestamp if self.preserve_timestamps else time.time()
        data = bytes(msg.data)
        all_sent = True
        for bus_queue in self.channel:
            if bus_queue is self.queue and not self.receive_own_messages:
                continue
            copy = can.Message(
                timestamp=timestamp, arbitration_id=msg.arbitration_id,
                is_extended_id=msg.is_extended_id, is_remote_frame=msg.is_remote_frame,
                is_error_frame=msg.is_error_frame, channel=self.channel_id, dlc=msg.dlc,
                data=data, is_fd=msg.is_fd, is_rx=bus_queue is not self.queue,
                bitrate_switch=msg.bitrate_switch, error_state_indicator=msg.error_state_indicator,
            )
            try:
                bus_queue.put(copy, block=True, timeout=timeout)
            except queue.Full:
                all_sent = False
        if not all_sent:
            raise can.CanOperationError("Could not send message to one or more recipients")


    def recv(self, timeout: float | None = None) -> can.Message | None:
        """python-can's ``recv``; a poll (``timeout=0``, the flight drivers' every call) takes
        the next queued frame that passes the filters without the timed wait loop."""
        if timeout != 0.0:
            return super().recv(timeout)
        self._check_if_open()
        while True:
            try:
                msg = self.queue.get_nowait()
            except queue.Empty:
                return None
            if self._matches_filters(msg):
                return msg


def open_bus(**kwargs: Any) -> can.BusABC:
    """``can.Bus(**kwargs)``; an :class:`InprocBus` for the ``virtual`` interface, and python-can's
    ``udp_multicast`` pinned to ``interface_name`` (:mod:`fsw.drivers.can_multicast`)."""
    kw = {k: v for k, v in kwargs.items() if k != "interface"}
    if kwargs.get("interface") == "virtual":
        return InprocBus(**kw)
    if kwargs.get("interface") == "udp_multicast" and kw.get("interface_name"):
        from fsw.drivers.can_multicast import PinnedMulticastBus

        return PinnedMulticastBus(**kw)
    return can.Bus(**kwargs)
