"""Lockstep simulation of one map transfer over the radio channel model (docs/algorithm.md §6.6).

The flight link (``fsw.comm.link_sender.LinkSender`` on side ``a``, the Cliff-bot's
``LinkReceiver`` on side ``b``) and :class:`hil_sim.link.radio_channel.RadioChannel` advance on
one simulated clock that jumps from event to event (the next protocol deadline or packet
arrival), so an hour of radio time takes well under a second and a seed fixes the run.
Used by the link tests, ``safer-hil experiment link`` and the Cliff-bot demo. A
:class:`Restart` takes one end down for a while (everything arriving there is lost) and
brings it back as a new instance with no memory, as a process restart does.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from fsw.comm.link import LinkConfig
from fsw.comm.link_receiver import LinkReceiver
from fsw.comm.link_sender import LinkSender, SenderState
from fsw.framework.events import PendingEvent
from hil_sim.link.radio_channel import DirectionStats, RadioChannel, RadioChannelConfig


@dataclass(frozen=True)
class Restart:
    """End ``side`` ("tx" sender, "rx" receiver) stops at ``at_s`` and starts afresh
    ``down_s`` later; a restarted sender offers the same map as session ``session`` (None:
    the session it started with, as a flight computer that counts sessions from boot)."""

    side: str
    at_s: float
    down_s: float = 1.0
    session: int | None = None


@dataclass
class TransferResult:
    delivered: bytes | None  # what the receiver accepted (None: nothing)
    delivered_s: float | None  # simulated time of acceptance
    sender_state: SenderState
    end_s: float
    sender_stats: dict[str, int]
    receiver_stats: dict[str, int]
    forward: DirectionStats
    reverse: DirectionStats
    events: list[tuple[str, PendingEvent]] = field(default_factory=list)
    idle_steps: int = 0  # steps where a deadline was due but nothing happened (should be 0)
    sender_done_s: float | None = None  # when the sender got the whole-map acknowledgement
    receiver_closed_s: float | None = None  # when the receiver's close ended (close=True runs)

    @property
    def goodput_bps(self) -> float:
        if self.delivered is None or not self.delivered_s:
            return 0.0
        return 8.0 * len(self.delivered) / self.delivered_s


def run_transfer(
    data: bytes, link: LinkConfig, channel: RadioChannelConfig, seed: int = 0,
    *, map_id: int = 1, session: int = 1, t_max_s: float = 7200.0, max_steps: int = 2_000_000,
    tamper: Callable[[str, bytes], bytes | None] | None = None, close: bool = False,
    restarts: Sequence[Restart] = (),
) -> TransferResult:
    """Send ``data`` from the RECON-bot to the Cliff-bot; stop when both ends are done.

    With ``close`` the run goes on until the receiver's close has ended too (FIN_ACK or
    ``fin_linger_s``), so the close itself can be checked.

    ``tamper(side, datagram)`` is the fault-injection backdoor: it sees every datagram
    arriving at ``side`` ("a" sender, "b" receiver) and returns it, a changed copy, or None
    to drop it. ``restarts``: ends taken down and brought back (:class:`Restart`).
    """
    ch = RadioChannel(channel, seed)
    tx, rx = LinkSender(link, session), LinkReceiver(link)
    t = 0.0
    tx.start(map_id, data, t)
    delivered: bytes | None = None
    delivered_s: float | None = None
    events: list[tuple[str, PendingEvent]] = []
    idle_steps = 0
    closed_s: float | None = None
    pending = sorted(restarts, key=lambda r: r.at_s)
    down: dict[str, Restart] = {}  # ends that are down now
    for _ in range(max_steps):
        while pending and t >= pending[0].at_s:
            r = pending.pop(0)
            down[r.side] = r
            events.append((r.side, PendingEvent(t, "STOPPED")))
        for r in [r for r in down.values() if t >= r.at_s + r.down_s]:
            del down[r.side]
            events.append((r.side, PendingEvent(t, "RESTARTED")))
            if r.side == "rx":
                rx = LinkReceiver(link)
            else:
                tx = LinkSender(link, session if r.session is None else r.session)
                tx.start(map_id, data, t)
        for side, end in (("a", tx), ("b", rx)):
            for d in ch.receive(side, t):
                d2 = tamper(side, d) if tamper is not None else d
                if d2 is not None and ("tx" if side == "a" else "rx") not in down:
                    end.receive(d2, t)
        if "tx" not in down:
            for d in tx.poll(t):
                ch.send("a", d, t)
        if "rx" not in down:
            for d in rx.poll(t):
                ch.send("b", d, t)
        got = rx.take_map()
        if got is not None and delivered is None:
            delivered, delivered_s = got[1], t
        rx_events = rx.events.pop_all()
        if closed_s is None and any(e.name == "CLOSED" for e in rx_events):
            closed_s = t
        events += [("tx", e) for e in tx.events.pop_all()] + [("rx", e) for e in rx_events]
        if tx.finished and delivered is not None and ch.next_arrival_s() is None \
                and not (close and rx.closing) and not down and not pending:
            break
        if tx.finished and tx.state is not SenderState.DONE:
            break
        ends = [e.next_deadline_s() for s, e in (("tx", tx), ("rx", rx)) if s not in down]
        nxt = [x for x in (*ends, ch.next_arrival_s(), *(r.at_s + r.down_s for r in down.values()),
                           pending[0].at_s if pending else None) if x is not None]
        if not nxt:
            break
        t_next = min(nxt)
        if t_next <= t:  # a deadline already due yet nothing happened: step on, count it
            idle_steps += 1
            t_next = t + 1e-3
        t = t_next
        if t > t_max_s:
            break
    return TransferResult(
        delivered=delivered, delivered_s=delivered_s, sender_state=tx.state, end_s=t,
        sender_stats=vars(tx.stats).copy(), receiver_stats=vars(rx.stats).copy(),
        forward=ch.stats("a"), reverse=ch.stats("b"), events=events, idle_steps=idle_steps,
        sender_done_s=tx.delivered_s, receiver_closed_s=closed_s)
