"""The RECON-bot to Cliff-bot map link: configuration and the parts both ends share.

docs/algorithm.md §6.6 ("transmit to the Cliff-bot with handshaking and checksums"), built as a
CFDP class 2 style reliable transfer over a lossy, bandwidth-capped datagram radio:

* :class:`~fsw.comm.link_sender.LinkSender` (RECON-bot) and
  :class:`~fsw.comm.link_receiver.LinkReceiver` (Cliff-bot) are sans-I/O state machines:
  ``receive(datagram, now_s)`` takes bytes in, ``poll(now_s)`` returns the datagrams to send
  now, ``next_deadline_s()`` says when to call ``poll`` again. No sockets, no clock, no
  threads, so the same code runs in lockstep over a simulated channel, over UDP and over
  a serial radio modem (``fsw.drivers.radio``).
* Packet formats: ``fsw.comm.link_packets``; state machines and timers: docs/link.md.

Both ends pace their output to ``rate_bps`` with :class:`Pacer` and report what happens
as :class:`PendingEvent` records in a bounded queue.
"""

from __future__ import annotations

from dataclasses import dataclass

from fsw.framework.params import param


@dataclass(frozen=True)
class LinkConfig:
    """Map link parameters (``[link]`` in config/fsw.toml)."""

    transport: str = param("inproc://radio", doc="radio URL: inproc://NAME, udp://HOST:PORT, "
                           "serial:PORT@BAUD (see fsw.drivers.radio)")
    peer: str = param("", doc="udp only: the other end's udp://HOST:PORT (empty: reply to sender)")
    rate_bps: float = param(9600.0, lo=300.0, hi=1e8, units="bit/s",
                            doc="radio bit rate; every packet is paced to it")
    pacing_catchup_s: float = param(0.05, lo=0.0, hi=1.0, units="s",
                                    doc="a packet sent up to this late does not delay the next "
                                    "(driver wake-up jitter); 0 = strict pacing")
    segment_bytes: int = param(464, lo=16, hi=8192, units="B", doc="map bytes per DATA packet")
    max_map_bytes: int = param(1 << 22, lo=1024, hi=1 << 28, units="B",
                               doc="largest map a receiver accepts (bounds its memory)")
    offer_retry_s: float = param(1.0, lo=0.05, hi=60.0, units="s",
                                 doc="first OFFER retry; doubles up to max_backoff_s")
    max_backoff_s: float = param(16.0, lo=0.1, hi=600.0, units="s")
    status_period_s: float = param(0.5, lo=0.05, hi=60.0, units="s",
                                   doc="receiver: STATUS at least this often while data flows")
    min_status_interval_s: float = param(0.25, lo=0.0, hi=10.0, units="s",
                                         doc="receiver: STATUS at most this often (PING excepted)")
    keepalive_s: float = param(5.0, lo=0.1, hi=600.0, units="s",
                               doc="receiver: STATUS keep-alive on an idle open session")
    ping_period_s: float = param(0.25, lo=0.05, hi=60.0, units="s",
                                 doc="sender: PING period while waiting for feedback")
    stall_timeout_s: float = param(5.0, lo=0.1, hi=600.0, units="s",
                                   doc="sender: no feedback this long = outage; pause data, PING")
    reorder_slack_s: float = param(0.5, lo=0.0, hi=60.0, units="s",
                                   doc="sender: a segment is lost once one sent this much later arrived")
    reoffer_s: float = param(10.0, lo=0.1, hi=3600.0, units="s",
                             doc="sender: no feedback this long = the OFFER is repeated (every "
                             "reoffer_s, between the PINGs) in case the receiver restarted")
    give_up_s: float = param(900.0, lo=1.0, hi=86400.0, units="s",
                             doc="either end: no packet from the peer this long ends the session")
    fin_linger_s: float = param(30.0, lo=0.0, hi=3600.0, units="s",
                                doc="receiver: repeat FIN until FIN_ACK or this long")
    close_tries: int = param(8, lo=1, hi=1000,
                             doc="sender: FIN_ACKs at most (one per FIN) before it gives up the close")
    max_bitmap_bytes: int = param(64, lo=1, hi=255, units="B",
                                  doc="selective-ack window in a STATUS (8 segments per byte)")
    max_restarts: int = param(3, lo=0, hi=100, doc="sender: resends after a hash mismatch")
    misfit_limit: int = param(8, lo=1, hi=65535,
                              doc="receiver: this many DATA in a row that do not fit the session held "
                              "(a forged OFFER) drop it; NO_SESSION makes the sender offer again")

    def __post_init__(self) -> None:
        if self.max_backoff_s < self.offer_retry_s:
            raise ValueError("max_backoff_s must be at least offer_retry_s")
        if self.max_map_bytes > 0xFFFF * self.segment_bytes:
            raise ValueError("max_map_bytes needs more than 65535 segments of segment_bytes")


class Pacer:
    """Pacing to ``rate_bps``: a packet of ``n`` bytes occupies ``8 n / rate`` seconds.

    ``catchup_s`` > 0 makes it a token bucket of that depth: a packet sent late by up to
    ``catchup_s`` (a driver that woke late) is charged from when it was due, so wake-up
    jitter does not lower the long-run rate; the rate itself is never exceeded by more
    than ``catchup_s`` worth of bytes.
    """

    def __init__(self, rate_bps: float, catchup_s: float = 0.0) -> None:
        self.rate_bps = rate_bps
        self.catchup_s = catchup_s
        self.free_at_s = float("-inf")

    def ready(self, now_s: float) -> bool:
        return now_s >= self.free_at_s - 1e-9

    def consume(self, nbytes: int, now_s: float) -> None:
        self.free_at_s = max(self.free_at_s, now_s - self.catchup_s) + 8.0 * nbytes / self.rate_bps


@dataclass
class LinkStats:
    """Counters both ends keep (telemetry)."""

    packets_out: int = 0
    bytes_out: int = 0
    packets_in: int = 0
    bad_packets: int = 0  # CRC, format
    foreign_packets: int = 0  # valid but for another session or state
    data_sent: int = 0
    retransmits: int = 0
    duplicates: int = 0
    statuses: int = 0
    pings: int = 0
    redundant: int = 0  # sender: copies of unacknowledged segments sent while the link was idle
    reoffers: int = 0  # sender: transfers offered again (the receiver lost the session, silence)
    no_session: int = 0  # receiver: NO_SESSION answers sent

    def count_out(self, datagram: bytes) -> bytes:
        self.packets_out += 1
        self.bytes_out += len(datagram)
        return datagram
