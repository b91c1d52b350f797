"""One agent's end of a two-way map sync: a sender and a receiver on one radio (docs/algorithm.md §6.6).

The team's agents exchange maps both ways over the same radio (docs/link.md, two-way): each
agent runs a :class:`~fsw.comm.link_sender.LinkSender` for its own map and a
:class:`~fsw.comm.link_receiver.LinkReceiver` for its peer's. :class:`LinkPeer` puts the
two behind the one sans-I/O interface of a link end:

* every datagram goes to the end it is for, by its packet type
  (``link_packets.TO_SENDER``: ACCEPT, REJECT, STATUS, FIN and NO_SESSION are answers to
  this agent's sender; everything else is for its receiver). Sessions of the two directions
  are independent: each sender numbers its own;
* both ends share one :class:`~fsw.comm.link.Pacer`, so together they never exceed
  ``rate_bps``; the receiver's answers go before the sender's data (an answer waits at most
  one DATA packet);
* a restart of either agent is a restart of both its ends, and each direction recovers as
  the one-way link does: NO_SESSION and a re-offer toward the restarted receiver, a resume
  from the peer's STATUS for the restarted sender.
"""

from __future__ import annotations

from fsw.comm import link_packets as lp
from fsw.comm.link import LinkConfig, Pacer
from fsw.comm.link_receiver import LinkReceiver
from fsw.comm.link_sender import LinkSender


class LinkPeer:
    """A sender and a receiver on one radio; ``receive``/``poll``/``next_deadline_s``."""

    def __init__(self, cfg: LinkConfig, session: int = 1) -> None:
        self.pacer = Pacer(cfg.rate_bps, cfg.pacing_catchup_s)
        self.tx = LinkSender(cfg, session, pacer=self.pacer)
        self.rx = LinkReceiver(cfg, pacer=self.pacer)

    def receive(self, datagram: bytes, now_s: float) -> None:
        """Route one datagram to the end it is for (an unknown type: the receiver counts it)."""
        end = self.tx if lp.packet_type(datagram) in lp.TO_SENDER else self.rx
        end.receive(datagram, now_s)

    def poll(self, now_s: float) -> list[bytes]:
        """The datagrams of both ends due now: answers first, then data, one pacing."""
        return self.rx.poll(now_s) + self.tx.poll(now_s)

    def next_deadline_s(self) -> float | None:
        times = [t for t in (self.tx.next_deadline_s(), self.rx.next_deadline_s()) if t is not None]
        return min(times) if times else None
