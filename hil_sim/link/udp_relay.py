"""An impairment relay for the map link over real UDP sockets (docs/algorithm.md §6.6; docs/link.md).

Two UDP sockets on 127.0.0.1: side ``a`` faces the RECON-bot, side ``b`` the Cliff-bot.
Every datagram that arrives on one side goes through the bench's seeded channel model
(:class:`hil_sim.link.radio_channel.RadioChannel`: a drop-tail queue serialised at ``rate_bps``,
latency, loss, bit errors, duplication, hold-back reordering and outage windows) on the
relay's monotonic clock, and leaves from the other side when the model says it arrives. So
the UDP bench and the lockstep simulation share one definition of every impairment; only
the clock differs (wall time from the first datagram here, so outage windows count from
the start of the transfer, so a run is seeded but not bit-for-bit repeatable:
packet timing on a loaded machine decides which random draw meets which packet).

Side ``a``'s peer is whoever sent to it last (the rover binds anywhere); side ``b``'s peer
is given (``b_peer``), since the Cliff-bot only answers. The relay stops by itself: after
``duration_s``, or ``idle_exit_s`` without a datagram once traffic has started.
"""

from __future__ import annotations

import select
import socket
import time
from dataclasses import asdict, dataclass
from typing import Any

from hil_sim.link.radio_channel import RadioChannel, RadioChannelConfig

LOOPBACK = "127.0.0.1"


@dataclass
class RelayResult:
    started_wall_s: float  # time.time() of the first datagram: t = 0 of the channel and its outages
    run_s: float
    a_to_b: dict[str, int]
    b_to_a: dict[str, int]
    stopped: str  # "idle", "duration"


class UdpRelay:
    """The relay; ``address("a")`` / ``address("b")`` are its two loopback ports."""

    def __init__(self, channel: RadioChannelConfig, seed: int, b_peer: tuple[str, int],
                 a_port: int = 0, b_port: int = 0) -> None:
        if b_peer[0] != LOOPBACK:
            raise ValueError(f"the relay serves loopback only, not {b_peer[0]}")
        self.channel = RadioChannel(channel, seed)
        self.socks = {side: socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for side in "ab"}
        for side, port in (("a", a_port), ("b", b_port)):
            self.socks[side].setblocking(False)
            self.socks[side].bind((LOOPBACK, port))
        self.peers: dict[str, tuple[str, int] | None] = {"a": None, "b": b_peer}
        self.send_errors = 0

    def address(self, side: str) -> tuple[str, int]:
        host, port = self.socks[side].getsockname()
        return str(host), int(port)

    def close(self) -> None:
        for s in self.socks.values():
            s.close()

    def run(self, duration_s: float, idle_exit_s: float) -> RelayResult:
        """Relay until ``duration_s`` or ``idle_exit_s`` of silence after the first datagram."""
        start = time.monotonic()
        t0 = start  # channel time 0: moved to the first datagram when it arrives
        wall0 = time.time()
        last_rx: float | None = None
        by_sock = {s.fileno(): side for side, s in self.socks.items()}
        stopped = "duration"
        while True:
            now = time.monotonic() - t0
            if time.monotonic() - start >= duration_s:
                break
            if last_rx is not None and now - last_rx >= idle_exit_s:
                stopped = "idle"
                break
            nxt = self.channel.next_arrival_s()
            wait = 0.05 if nxt is None else min(0.05, max(0.0, nxt - now))
            ready, _, _ = select.select(list(self.socks.values()), [], [], wait)
            if last_rx is None and ready:
                t0, wall0 = time.monotonic(), time.time()
            now = time.monotonic() - t0
            for s in ready:
                side = by_sock[s.fileno()]
                while True:
                    try:
                        data, addr = s.recvfrom(65535)
                    except (BlockingIOError, InterruptedError):
                        break
                    except OSError:
                        break  # e.g. ICMP port unreachable reported on a UDP socket
                    last_rx = now
                    if side == "a":
                        self.peers["a"] = (addr[0], addr[1])
                    self.channel.send(side, data, now)
            for side in "ab":
                peer = self.peers[side]
                for data in self.channel.receive(side, now):
                    if peer is None:
                        continue
                    try:
                        self.socks[side].sendto(data, peer)
                    except OSError:
                        self.send_errors += 1
        return RelayResult(wall0, round(time.monotonic() - start, 3),
                           asdict(self.channel.stats("a")), asdict(self.channel.stats("b")), stopped)


def relay_summary(res: RelayResult) -> dict[str, Any]:
    """The relay's figures as one JSON-able dict."""
    return {"relay": asdict(res)}
