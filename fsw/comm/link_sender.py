"""Sending end of the map link (RECON-bot), sans-I/O (docs/algorithm.md §6.6; docs/link.md).

States: ``IDLE -> OFFERING -> SENDING -> DONE``, or ``REJECTED`` / ``FAILED``; ``SENDING ->
OFFERING`` again when the receiver has lost the session (a restart), or when a REJECT comes
while no OFFER of this sender is out (the receiver refused a forged one).

* OFFERING: OFFER (map id, size, segment size, SHA-256) repeated with exponential backoff
  until ACCEPT (or a STATUS, if the ACCEPT was lost) or REJECT.
* SENDING: DATA packets paced to the bit rate: retransmissions first (lowest segment
  first), then new segments in order. Every transmission carries a serial; each STATUS
  echoes the serial of the last packet that reached the receiver, and a segment that is
  not acknowledged although a packet sent ``reorder_slack_s`` after it arrived is lost
  (time-based loss detection as TCP RACK, RFC 8985) and queued for retransmission. When
  all segments are out, a PING (right away, then every ``ping_period_s``) asks for a STATUS
  so tail losses are found within a round trip. A pacer slot with nothing else to send
  carries a copy of an unacknowledged segment (round robin, oldest first), so the link
  never idles while the tail's fate is unknown: retransmission is driven by the gaps the
  STATUS reports and by otherwise idle air time, never by a per-segment timer.
* Restart of the receiver (or a session it dropped, its data not fitting the parameters
  it held: a forged OFFER): its NO_SESSION answer to DATA or PING makes the sender offer
  again at once under a new session (progress cleared: the receiver's ACCEPT or STATUS says
  what it holds; event REOFFERED); after ``reoffer_s`` of silence, an OFFER of the same
  session takes the place of a PING every ``reoffer_s`` (an ACCEPT to it = the receiver
  holds nothing, progress cleared). Restart of the sender: the new sender's OFFER of the
  same map is answered with a STATUS of what the receiver holds (receiver docstring).
* Outage: no feedback for ``stall_timeout_s`` pauses data and sends only PINGs; the first
  STATUS after the outage says exactly which segments are missing, so nothing that
  arrived is sent again. No feedback for ``give_up_s``: FAILED.
* DONE on FIN(VERIFIED), the whole-map acknowledgement: the map is delivered at once (event
  DELIVERED), whatever else is still in flight. DONE has no timer: it only answers each FIN
  with a FIN_ACK, at most ``close_tries`` of them; a FIN after that gives up the close (event
  CLOSE_GIVEN_UP) and is ignored, the receiver ends its linger by itself. FIN(HASH_MISMATCH)
  restarts the transfer, at most ``max_restarts`` times. The FIN is sent once: if it is lost,
  the receiver's next STATUS gives the mismatch away, as a STATUS is generated after every
  segment the sender counts as held was reported held (it echoes a packet sent after the last
  new acknowledgement arrived) yet reports fewer segments held: the receiver discarded them,
  and the transfer restarts the same way (event HASH_MISMATCH_RESEND, ``inferred``).

Memory: the map itself plus a few bytes per segment and a 1024-entry serial ring.
"""

from __future__ import annotations

import hashlib
import heapq
from enum import Enum

from fsw.comm import link_packets as lp
from fsw.comm.link import LinkConfig, LinkStats, Pacer
from fsw.framework.events import EventSink

_RING = 1024
_NEVER = float("-inf")
_EPS = 1e-9  # deadlines are met within this (float rounding of t0 + period)


class SenderState(Enum):
    IDLE = "idle"
    OFFERING = "offering"
    SENDING = "sending"
    DONE = "done"
    REJECTED = "rejected"
    FAILED = "failed"


class LinkSender:
    """Sends one map at a time; see the module docstring for the protocol."""

    def __init__(self, cfg: LinkConfig, session: int = 1, pacer: Pacer | None = None) -> None:
        self.cfg = cfg
        self.session = session & 0xFFFF
        self.state = SenderState.IDLE
        self.stats = LinkStats()
        self.events = EventSink()
        # ``pacer``: shared with a receiver on the same radio (fsw.comm.link_peer)
        self._pacer = pacer if pacer is not None else Pacer(cfg.rate_bps, cfg.pacing_catchup_s)
        self._data = b""
        self._map_id = 0
        self._n = 0
        self._acked = bytearray()
        self._last_sent: list[float] = []
        self._lost: list[int] = []  # heap of segments to retransmit
        self._queued = bytearray()
        self._next_new = 0
        self._serial = 0
        self._ring_serial = [-1] * _RING
        self._ring_time = [0.0] * _RING
        self._rack_s = _NEVER
        self.srtt_s: float | None = None
        self._n_acked = 0
        self._cum = 0
        self._acked_news_s = _NEVER  # arrival of the last STATUS that acknowledged a new segment
        self._restarts = 0
        self._start_s = 0.0
        self._last_feedback_s = 0.0
        self._next_offer_s = 0.0
        self._backoff_s = cfg.offer_retry_s
        self._offer_sent_s = _NEVER
        self._next_ping_s = _NEVER
        self._data_since_ping = False
        self._fin_acks = 0  # FIN_ACKs owed (one per FIN(VERIFIED) received)
        self._fin_acks_sent = 0
        self._close_given_up = False
        self._probe_at_s = _NEVER  # silence: next OFFER in place of a PING
        self._probing = False  # an OFFER went out since the last feedback (SENDING)
        self._tail_ptr = 0  # round robin over unacknowledged segments (idle-slot copies)
        self.delivered_s: float | None = None  # when the whole-map acknowledgement arrived
        self._now_s = 0.0  # time of the last receive/poll call

    # -- public API ------------------------------------------------------------------------
    def start(self, map_id: int, data: bytes, now_s: float) -> None:
        """Begin offering ``data`` (one map container) as map ``map_id``."""
        if not 1 <= len(data) <= self.cfg.max_map_bytes:
            raise ValueError(f"map of {len(data)} bytes outside 1..{self.cfg.max_map_bytes}")
        self._data = bytes(data)
        self._map_id = map_id & 0xFFFFFFFF
        self._n = -(-len(data) // self.cfg.segment_bytes)
        self._digest = hashlib.sha256(self._data).digest()
        self._reset_progress()
        self._fin_acks = self._fin_acks_sent = 0
        self._close_given_up = False
        self.delivered_s = None
        self.state = SenderState.OFFERING
        self._start_s = self._last_feedback_s = self._now_s = now_s
        self._next_offer_s = now_s
        self._backoff_s = self.cfg.offer_retry_s
        self.events.emit(now_s, "OFFERED", map_id=self._map_id, size=len(data), segments=self._n)

    @property
    def map_id(self) -> int:
        return self._map_id

    @property
    def map_bytes(self) -> int:
        return len(self._data)

    @property
    def progress(self) -> tuple[int, int]:
        """(segments acknowledged, segments in the map)."""
        return self._n_acked, self._n

    @property
    def close_given_up(self) -> bool:
        """True once ``close_tries`` FIN_ACKs were spent and another FIN still came."""
        return self._close_given_up

    @property
    def finished(self) -> bool:
        return self.state in (SenderState.DONE, SenderState.REJECTED, SenderState.FAILED)

    def receive(self, datagram: bytes, now_s: float) -> None:
        """Handle one datagram from the radio (anything invalid is counted and dropped)."""
        self.stats.packets_in += 1
        self._now_s = max(self._now_s, now_s)
        try:
            pkt = lp.decode(datagram)
        except lp.PacketError:
            self.stats.bad_packets += 1
            return
        if pkt.session != self.session or self.state is SenderState.IDLE:
            self.stats.foreign_packets += 1
            return
        if isinstance(pkt, lp.Fin) and pkt.map_id == self._map_id:
            self._on_fin(pkt, now_s)
        elif self.state not in (SenderState.OFFERING, SenderState.SENDING):
            self.stats.foreign_packets += 1
        elif isinstance(pkt, lp.NoSession) and self.state is SenderState.SENDING:
            self._reoffer(now_s, "the receiver holds no session")
        elif isinstance(pkt, lp.Accept) and pkt.map_id == self._map_id:
            if self.state is SenderState.SENDING and self._probing:
                self._reset_progress()  # the receiver took the OFFER afresh: it holds nothing
                self._probing = False
                self._last_feedback_s = now_s
                self.events.emit(now_s, "ACCEPTED", map_id=self._map_id)
            self._on_accept(now_s)
        elif isinstance(pkt, lp.Reject) and pkt.map_id == self._map_id:
            if self.state is SenderState.SENDING and not self._probing:
                # no OFFER of ours is out (it was accepted; no probe since): the receiver refused an
                # OFFER this sender did not send (a forgery past CRC-32) and may hold nothing now
                self._reoffer(now_s, "a REJECT of an OFFER this sender did not send")
            else:
                self.state = SenderState.REJECTED
                self.events.emit(now_s, "REJECTED", map_id=self._map_id, reason=pkt.reason.name)
        elif isinstance(pkt, lp.Status):
            if self.state is SenderState.OFFERING:
                self._on_accept(now_s)
            self._on_status(pkt, now_s)
        else:
            self.stats.foreign_packets += 1

    def poll(self, now_s: float, max_bytes: int | None = None) -> list[bytes]:
        """Datagrams to send now, within pacing and an optional byte budget."""
        out: list[bytes] = []
        used = 0
        self._now_s = max(self._now_s, now_s)
        self._check_timeouts(now_s)
        while self._pacer.ready(now_s):
            if max_bytes is not None and used + self.cfg.segment_bytes + lp.DATA_OVERHEAD > max_bytes:
                break
            pkt = self._next_packet(now_s)
            if pkt is None:
                break
            self._pacer.consume(len(pkt), now_s)
            used += len(pkt)
            out.append(self.stats.count_out(pkt))
        return out

    def next_deadline_s(self) -> float | None:
        """When ``poll`` next has something to do (None: nothing until a packet arrives)."""
        s = self.state
        if s is SenderState.IDLE or (self.finished and not self._fin_acks):
            return None
        if self._fin_acks:
            return self._pacer.free_at_s
        if s is SenderState.OFFERING:
            return min(max(self._next_offer_s, self._pacer.free_at_s),
                       self._last_feedback_s + self.cfg.give_up_s)
        cand = [self._last_feedback_s + self.cfg.give_up_s]
        stalled = self._stalled(self._now_s)
        if not stalled and (self._lost or self._next_new < self._n or self._n_acked < self._n):
            cand.append(self._pacer.free_at_s)
        else:
            ping_at = self._next_ping_s if stalled or not self._data_since_ping else _NEVER
            cand.append(max(ping_at, self._pacer.free_at_s))
        if not stalled:
            cand.append(self._last_feedback_s + self.cfg.stall_timeout_s)
        return min(cand)

    # -- internals ---------------------------------------------------------------------------
    def _reset_progress(self) -> None:
        self._acked = bytearray(self._n)
        self._queued = bytearray(self._n)
        self._last_sent = [_NEVER] * self._n
        self._lost = []
        self._next_new = 0
        self._n_acked = 0
        self._cum = 0
        self._acked_news_s = _NEVER
        self._rack_s = _NEVER
        self._data_since_ping = False
        self._tail_ptr = 0

    def _stalled(self, now_s: float) -> bool:
        return now_s - self._last_feedback_s >= self.cfg.stall_timeout_s - _EPS

    def _check_timeouts(self, now_s: float) -> None:
        if self.state in (SenderState.OFFERING, SenderState.SENDING) and \
                now_s - self._last_feedback_s > self.cfg.give_up_s:
            self.state = SenderState.FAILED
            self.events.emit(now_s, "LINK_LOST", map_id=self._map_id,
                             silent_s=round(now_s - self._last_feedback_s, 1))

    def _next_packet(self, now_s: float) -> bytes | None:
        if self._fin_acks:
            self._fin_acks -= 1
            self._fin_acks_sent += 1
            return lp.encode(lp.FinAck(self.session, self._map_id))
        if self.state is SenderState.OFFERING:
            if now_s < self._next_offer_s - _EPS:
                return None
            self._next_offer_s = now_s + self._backoff_s
            self._backoff_s = min(2 * self._backoff_s, self.cfg.max_backoff_s)
            self._offer_sent_s = now_s
            return lp.encode(lp.Offer(self.session, self._map_id, len(self._data),
                                      self.cfg.segment_bytes, self._digest))
        if self.state is not SenderState.SENDING:
            return None
        stalled = self._stalled(now_s)
        if not stalled:
            while self._lost:
                seq = heapq.heappop(self._lost)
                self._queued[seq] = 0
                if not self._acked[seq]:
                    self.stats.retransmits += 1
                    return self._data_packet(seq, now_s)
            while self._next_new < self._n and self._acked[self._next_new]:
                self._next_new += 1  # already there (a resumed transfer)
            if self._next_new < self._n:
                self._next_new += 1
                return self._data_packet(self._next_new - 1, now_s)
        if now_s >= self._next_ping_s - _EPS or (self._data_since_ping and not stalled):
            self._data_since_ping = False
            self._next_ping_s = now_s + self.cfg.ping_period_s
            silent_s = now_s - self._last_feedback_s
            if silent_s >= self.cfg.reoffer_s - _EPS and now_s >= self._probe_at_s - _EPS:
                return self._probe_offer(now_s, silent_s)
            self.stats.pings += 1
            return lp.encode(lp.Ping(self.session, self._take_serial(now_s),
                                     self._next_new >= self._n))
        copy = None if stalled else self._idle_copy()
        if copy is not None:
            self.stats.redundant += 1
            return self._data_packet(copy, now_s)
        return None

    def _idle_copy(self) -> int | None:
        """An unacknowledged segment to send again in an otherwise idle slot (round robin)."""
        if self._next_new < self._n or self._n_acked >= self._n:
            return None
        for _ in range(self._n):
            seq = self._tail_ptr
            self._tail_ptr = seq + 1 if seq + 1 < self._n else self._cum
            if not self._acked[seq]:
                return seq
        return None

    def _probe_offer(self, now_s: float, silent_s: float) -> bytes:
        """Silence: the OFFER again in place of a PING (a restarted receiver answers it)."""
        self._probe_at_s = now_s + self.cfg.reoffer_s
        if not self._probing:
            self._probing = True
            self.stats.reoffers += 1
            self.events.emit(now_s, "REOFFERED", map_id=self._map_id, session=self.session,
                             reason=f"no answer for {silent_s:.1f} s")
        return lp.encode(lp.Offer(self.session, self._map_id, len(self._data),
                                  self.cfg.segment_bytes, self._digest))

    def _reoffer(self, now_s: float, reason: str) -> None:
        """Offer the map again under a new session; nothing is assumed held until it answers."""
        self.session = self.session % 0xFFFF + 1
        self._reset_progress()
        self.state = SenderState.OFFERING
        self._last_feedback_s = now_s
        self._next_offer_s = now_s
        self._backoff_s = self.cfg.offer_retry_s
        self._probing = False
        self.stats.reoffers += 1
        self.events.emit(now_s, "REOFFERED", map_id=self._map_id, session=self.session, reason=reason)

    def _take_serial(self, now_s: float) -> int:
        s = self._serial
        self._serial = (s + 1) & 0xFFFF
        self._ring_serial[s % _RING] = s
        self._ring_time[s % _RING] = now_s
        return s

    def _data_packet(self, seq: int, now_s: float) -> bytes:
        seg = self.cfg.segment_bytes
        self._last_sent[seq] = now_s
        self._data_since_ping = True
        self.stats.data_sent += 1
        return lp.encode(lp.Data(self.session, seq, self._take_serial(now_s),
                                 self._data[seq * seg:(seq + 1) * seg]))

    def _on_accept(self, now_s: float) -> None:
        if self.state is not SenderState.OFFERING:
            return
        self.state = SenderState.SENDING
        self._last_feedback_s = now_s
        if self._offer_sent_s > _NEVER:
            self.srtt_s = now_s - self._offer_sent_s
        self.events.emit(now_s, "ACCEPTED", map_id=self._map_id)

    def _on_status(self, st: lp.Status, now_s: float) -> None:
        self.stats.statuses += 1
        self._last_feedback_s = now_s
        self._probing = False
        if st.highest > self._n:
            self.stats.foreign_packets += 1
            return
        echo_s = None
        if st.echo_serial is not None and self._ring_serial[st.echo_serial % _RING] == st.echo_serial:
            echo_s = self._ring_time[st.echo_serial % _RING]
        if echo_s is not None and echo_s > self._acked_news_s and st.n_received < self._n_acked \
                and self.state is SenderState.SENDING:
            # Generated after every acknowledgement counted here, yet holding fewer segments:
            # the receiver discarded its buffer (a hash mismatch whose FIN was lost).
            self._restart(now_s, inferred=True)
            if self.state is not SenderState.SENDING:
                return
        acked = self._n_acked
        for seq in range(self._cum, st.cum):
            self._ack(seq)
        self._cum = max(self._cum, st.cum)
        window_end = min(st.cum + 8 * len(st.bitmap), self._n)
        for i in range(window_end - st.cum):
            if st.bitmap[i >> 3] >> (i & 7) & 1:
                self._ack(st.cum + i)
        if self._n_acked > acked:
            self._acked_news_s = now_s
        if echo_s is not None:
            self._rack_s = max(self._rack_s, echo_s)
            rtt = now_s - echo_s
            self.srtt_s = rtt if self.srtt_s is None else 0.875 * self.srtt_s + 0.125 * rtt
        limit = self._rack_s - self.cfg.reorder_slack_s
        for seq in range(st.cum, self._next_new):
            known = seq < window_end or seq >= st.highest
            if known and not self._acked[seq] and not self._queued[seq] \
                    and self._last_sent[seq] < limit:
                self._queued[seq] = 1
                heapq.heappush(self._lost, seq)

    def _ack(self, seq: int) -> None:
        if not self._acked[seq]:
            self._acked[seq] = 1
            self._n_acked += 1

    def _on_fin(self, fin: lp.Fin, now_s: float) -> None:
        self._last_feedback_s = now_s
        self._probing = False
        if fin.status is lp.FinStatus.VERIFIED:
            if self.state is not SenderState.DONE:
                self.state = SenderState.DONE
                self._n_acked = self._n
                self._lost = []
                self.delivered_s = now_s
                self.events.emit(now_s, "DELIVERED", map_id=self._map_id, size=len(self._data),
                                 seconds=round(now_s - self._start_s, 3))
            if self._fin_acks_sent + self._fin_acks < self.cfg.close_tries:
                self._fin_acks += 1
            elif not self._close_given_up:
                self._close_given_up = True
                self.events.emit(now_s, "CLOSE_GIVEN_UP", map_id=self._map_id,
                                 fin_acks=self._fin_acks_sent)
        elif self.state is SenderState.SENDING and self._next_new >= self._n:
            # A mismatch needs every segment at the receiver, so one reported before this
            # attempt sent every segment is a duplicate or stale copy of the last one.
            self._restart(now_s, inferred=False)

    def _restart(self, now_s: float, inferred: bool) -> None:
        """The receiver discarded the map (hash mismatch): send it again, at most
        ``max_restarts`` times. ``inferred``: from a STATUS, the FIN being lost."""
        self._restarts += 1
        if self._restarts > self.cfg.max_restarts:
            self.state = SenderState.FAILED
            self.events.emit(now_s, "HASH_MISMATCH_GIVE_UP", map_id=self._map_id)
        else:
            self._reset_progress()
            self.events.emit(now_s, "HASH_MISMATCH_RESEND", map_id=self._map_id,
                             attempt=self._restarts, inferred=inferred)
