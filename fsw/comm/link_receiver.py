"""Receiving end of the map link (Cliff-bot), sans-I/O (docs/algorithm.md §6.6; docs/link.md).

States: ``IDLE -> RECEIVING -> COMPLETE -> IDLE``.

* An OFFER within ``max_map_bytes`` is accepted (ACCEPT); a bigger one is REJECTed. An
  OFFER for the map already partly held (same SHA-256, size and segment size: a repeated
  OFFER, or the sender restarted with a new session) is answered with a STATUS instead,
  which accepts it and lists what is already here, so none of it is sent again. An OFFER
  for a map already delivered (same SHA-256 as one of the last four verified) is answered
  with FIN(VERIFIED), and the close lingers again.
* DATA is checked (segment number, length) and stored once; duplicates are counted. A
  STATUS (cumulative ack, highest segment, a selective-ack bitmap of up to
  ``8 * max_bitmap_bytes`` segments, and the serial of the last packet seen) goes out when
  a gap opens, at least every ``status_period_s`` while data flows, every
  ``min_status_interval_s`` after an ACCEPT until the first DATA (at most ``keepalive_s``:
  a lost ACCEPT costs a fraction of a second, not an OFFER retry), at once on a PING, and
  every ``keepalive_s`` on an idle open session; never more often than
  ``min_status_interval_s`` except for PINGs.
* When every segment is in, the whole map's SHA-256 must equal the offer's before the map
  is accepted (``take_map``); then FIN(VERIFIED), the whole-map acknowledgement, is sent
  at once. The close: COMPLETE lingers, answering every packet of the session with the
  FIN and repeating it every ``status_period_s``, until FIN_ACK or ``fin_linger_s`` (event
  CLOSED either way); no state of the receiver waits for ``give_up_s`` once the map is
  verified. Afterwards a PING or DATA of a session whose map was verified (the last four)
  is still answered with FIN(VERIFIED), so a sender that missed every FIN learns of the
  delivery whenever it asks. On a mismatch the buffer is discarded and FIN(HASH_MISMATCH)
  asks the sender to start again.
* A DATA or PING of a session it holds nothing of (this receiver restarted, or dropped the
  session after ``give_up_s``) is answered with NO_SESSION, at most once per
  ``min_status_interval_s`` per session (event UNKNOWN_SESSION once per session), so the
  sender offers again instead of pinging into the void.
* A session whose data cannot be the map it holds is dropped the same way (event
  SESSION_DROPPED): ``misfit_limit`` DATA of it in a row that do not fit it (segment out of
  range, wrong length), or a second hash mismatch in it. Both mean the parameters it holds are
  not the sender's (a forged OFFER that passed CRC-32: another size, segment size or
  SHA-256); the NO_SESSION that answers makes the sender offer again under a new session, and
  that OFFER's parameters are taken afresh. The first hash mismatch still gets
  FIN(HASH_MISMATCH) (a corrupted DATA is the likelier cause).

Memory: one buffer of the offered size (at most ``max_map_bytes``) and one byte per segment.
"""

from __future__ import annotations

import hashlib
from collections import deque
from enum import Enum

from fsw.comm import link_packets as lp
from fsw.comm.link import LinkConfig, LinkStats, Pacer
from fsw.framework.events import EventSink

_EPS = 1e-9  # deadlines are met within this (float rounding of t0 + period)


class ReceiverState(Enum):
    IDLE = "idle"
    RECEIVING = "receiving"
    COMPLETE = "complete"


class LinkReceiver:
    """Receives maps; see the module docstring for the protocol."""

    def __init__(self, cfg: LinkConfig, pacer: Pacer | None = None) -> None:
        self.cfg = cfg
        self.state = ReceiverState.IDLE
        self.stats = LinkStats()
        self.events = EventSink()
        # ``pacer``: shared with a sender on the same radio (fsw.comm.link_peer)
        self._pacer = pacer if pacer is not None else Pacer(cfg.rate_bps, cfg.pacing_catchup_s)
        self._offer: lp.Offer | None = None
        self._buf = bytearray()
        self._have = bytearray()
        self._n_rx = 0
        self._cum = 0
        self._highest = 0
        self._echo: int | None = None
        self._all_sent = False
        self._last_rx_s = 0.0
        self._last_status_s = float("-inf")
        self._status_due = False
        self._status_now = False
        self._new_data = False
        self._replies: deque[bytes] = deque(maxlen=8)  # ACCEPT/REJECT answers (bounded)
        self._fin: lp.Fin | None = None
        self._fin_until_s = 0.0
        self._delivered: list[tuple[int, bytes]] = []
        # (session, map id, SHA-256) of the last maps verified
        self._verified: deque[tuple[int, int, bytes]] = deque(maxlen=4)
        self._unknown: dict[int, float] = {}  # session -> last NO_SESSION answer (bounded)
        self._start_s = 0.0
        self._misfits = 0  # DATA in a row that did not fit the session held
        self._mismatches = 0  # hash mismatches in the session held

    # -- public API ------------------------------------------------------------------------
    def take_map(self) -> tuple[int, bytes] | None:
        """The oldest verified map not yet taken, as (map id, bytes)."""
        return self._delivered.pop(0) if self._delivered else None

    @property
    def progress(self) -> tuple[int, int]:
        """(segments held, segments in the current map)."""
        return self._n_rx, self._offer.n_segments if self._offer else 0

    def receive(self, datagram: bytes, now_s: float) -> None:
        """Handle one datagram from the radio (anything invalid is counted and dropped)."""
        self.stats.packets_in += 1
        try:
            pkt = lp.decode(datagram)
        except lp.PacketError:
            self.stats.bad_packets += 1
            return
        if isinstance(pkt, lp.Offer):
            self._on_offer(pkt, now_s)
            return
        if self.state is ReceiverState.IDLE or self._offer is None \
                or pkt.session != self._offer.session:
            if isinstance(pkt, (lp.Data, lp.Ping)):
                if not self._answer_verified(pkt.session):
                    self.stats.foreign_packets += 1
                    self._answer_unknown(pkt.session, now_s)
            else:
                self.stats.foreign_packets += 1
            return
        self._last_rx_s = now_s
        if self.state is ReceiverState.COMPLETE:
            if isinstance(pkt, lp.FinAck):
                self._close(now_s, "fin_ack")
            elif isinstance(pkt, (lp.Data, lp.Ping)):
                self._status_now = True  # answer with the FIN again
            return
        if isinstance(pkt, lp.Data):
            self._on_data(pkt, now_s)
        elif isinstance(pkt, lp.Ping):
            self.stats.pings += 1
            self._echo = pkt.serial
            self._all_sent = self._all_sent or pkt.all_sent
            self._status_now = True
        else:
            self.stats.foreign_packets += 1

    def poll(self, now_s: float) -> list[bytes]:
        """Datagrams to send now, within pacing."""
        self._check_timeouts(now_s)
        out: list[bytes] = []
        while self._pacer.ready(now_s):
            pkt = self._next_packet(now_s)
            if pkt is None:
                break
            self._pacer.consume(len(pkt), now_s)
            out.append(self.stats.count_out(pkt))
        return out

    @property
    def closing(self) -> bool:
        """True while a verified map's close lingers (until FIN_ACK or ``fin_linger_s``)."""
        return self.state is ReceiverState.COMPLETE

    def next_deadline_s(self) -> float | None:
        """When ``poll`` next has something to do (None: nothing until a packet arrives)."""
        if self._replies or self._status_now:
            return self._pacer.free_at_s
        if self.state is ReceiverState.COMPLETE:
            return max(self._pacer.free_at_s, min(self._fin_until_s,
                                                  self._last_status_s + self.cfg.status_period_s))
        if self.state is not ReceiverState.RECEIVING:
            return None
        cand = [self._last_rx_s + self.cfg.give_up_s,
                self._last_status_s + self.cfg.keepalive_s]
        if self._status_due:
            cand.append(self._last_status_s + self.cfg.min_status_interval_s)
        if self._new_data:
            cand.append(self._last_status_s + self.cfg.status_period_s)
        repeat_s = self._last_status_s + self.cfg.min_status_interval_s
        if self._n_rx == 0 and repeat_s < self._start_s + self.cfg.keepalive_s:
            cand.append(repeat_s)
        return max(self._pacer.free_at_s, min(cand))

    # -- internals ---------------------------------------------------------------------------
    def _on_offer(self, offer: lp.Offer, now_s: float) -> None:
        cur = self._offer
        same_map = cur is not None and (cur.sha256, cur.size, cur.segment_bytes) == (
            offer.sha256, offer.size, offer.segment_bytes)
        if offer.size > self.cfg.max_map_bytes:
            self._replies.append(lp.encode(lp.Reject(offer.session, offer.map_id,
                                                     lp.RejectReason.TOO_LARGE)))
            self.events.emit(now_s, "OFFER_REJECTED", map_id=offer.map_id, size=offer.size)
            return
        self._last_rx_s = now_s
        done_before = any(d == offer.sha256 for _, _, d in self._verified)
        if (same_map and self.state is ReceiverState.COMPLETE) or (
                done_before and self.state is not ReceiverState.RECEIVING):
            # already delivered (a sender that restarted, or missed every FIN): confirm again
            # under the offer's session, and linger for its FIN_ACK
            self._offer = offer
            if not any(v[:2] == (offer.session, offer.map_id) for v in self._verified):
                self._verified.append((offer.session, offer.map_id, offer.sha256))
            self._fin = lp.Fin(offer.session, offer.map_id, lp.FinStatus.VERIFIED)
            self._fin_until_s = now_s + self.cfg.fin_linger_s
            self.state = ReceiverState.COMPLETE
            self._status_now = True
            return
        if same_map and self.state is ReceiverState.RECEIVING:
            if cur is not None and cur.session != offer.session:
                self.events.emit(now_s, "RESUMED", map_id=offer.map_id, held=self._n_rx)
            self._offer = offer
            self._status_now = True  # a STATUS accepts and says what is already here
            return
        self._offer = offer
        for old in [v for v in self._verified if v[0] == offer.session]:
            self._verified.remove(old)  # the session number is in use again
        self._buf = bytearray(offer.size)
        self._have = bytearray(offer.n_segments)
        self._n_rx = self._cum = self._highest = 0
        self._echo = None
        self._all_sent = False
        self._misfits = self._mismatches = 0
        self._start_s = now_s
        self.state = ReceiverState.RECEIVING
        self.events.emit(now_s, "OFFER_ACCEPTED", map_id=offer.map_id, size=offer.size)
        self._replies.append(lp.encode(lp.Accept(offer.session, offer.map_id)))

    def _on_data(self, d: lp.Data, now_s: float) -> None:
        offer = self._offer
        assert offer is not None
        seg = offer.segment_bytes
        n = offer.n_segments
        want = seg if d.seq < n - 1 else offer.size - seg * (n - 1)
        if d.seq >= n or len(d.payload) != want:
            self.stats.foreign_packets += 1
            self._misfits += 1
            if self._misfits >= self.cfg.misfit_limit:
                self._drop(now_s, f"{self._misfits} DATA in a row do not fit the offer")
            return
        self._misfits = 0
        self._echo = d.serial
        if self._have[d.seq]:
            self.stats.duplicates += 1
            return
        self._buf[d.seq * seg: d.seq * seg + want] = d.payload
        self._have[d.seq] = 1
        self._n_rx += 1
        self._new_data = True
        if d.seq > self._highest:
            self._status_due = True  # a gap opened
        self._highest = max(self._highest, d.seq + 1)
        while self._cum < n and self._have[self._cum]:
            self._cum += 1
        if self._n_rx == n:
            self._complete(now_s)

    def _complete(self, now_s: float) -> None:
        offer = self._offer
        assert offer is not None
        if hashlib.sha256(self._buf).digest() == offer.sha256:
            self._delivered = (self._delivered + [(offer.map_id, bytes(self._buf))])[-4:]
            self.state = ReceiverState.COMPLETE
            self._verified.append((offer.session, offer.map_id, offer.sha256))
            self._fin = lp.Fin(offer.session, offer.map_id, lp.FinStatus.VERIFIED)
            self.events.emit(now_s, "MAP_VERIFIED", map_id=offer.map_id, size=offer.size,
                             seconds=round(now_s - self._start_s, 3))
        else:
            self.events.emit(now_s, "HASH_MISMATCH", map_id=offer.map_id)
            self._mismatches += 1
            if self._mismatches >= 2:  # its SHA-256 is not the sender's (a forged OFFER)
                self._drop(now_s, "a second hash mismatch")
                return
            self._fin = lp.Fin(offer.session, offer.map_id, lp.FinStatus.HASH_MISMATCH)
            self._have = bytearray(offer.n_segments)
            self._n_rx = self._cum = self._highest = 0
        self._buf = bytearray(offer.size) if self.state is ReceiverState.RECEIVING else bytearray()
        self._fin_until_s = now_s + self.cfg.fin_linger_s
        self._status_now = True

    def _check_timeouts(self, now_s: float) -> None:
        if self.state is ReceiverState.RECEIVING and now_s - self._last_rx_s > self.cfg.give_up_s:
            self.events.emit(now_s, "SESSION_TIMEOUT", held=self._n_rx, of=self.progress[1])
            self._forget_session()
        if self.state is ReceiverState.COMPLETE and now_s >= self._fin_until_s - _EPS:
            self._close(now_s, "linger")

    def _forget_session(self) -> None:
        """Hold no session: its offer and buffers go (a timeout, or a session dropped)."""
        self.state = ReceiverState.IDLE
        self._offer = None
        self._buf, self._have = bytearray(), bytearray()

    def _drop(self, now_s: float, reason: str) -> None:
        """Drop a session whose data cannot be the map it holds (its OFFER was not the sender's)
        and answer NO_SESSION, so the sender offers again under a new session."""
        offer = self._offer
        assert offer is not None
        self.events.emit(now_s, "SESSION_DROPPED", map_id=offer.map_id, held=self._n_rx, reason=reason)
        self._forget_session()
        self._n_rx = self._cum = self._highest = 0
        self._fin = None
        self._status_now = self._status_due = self._new_data = False
        self._answer_unknown(offer.session, now_s, report=False)

    def _close(self, now_s: float, how: str) -> None:
        """End the linger of a verified map (FIN_ACK came, or ``fin_linger_s`` passed)."""
        self.state = ReceiverState.IDLE
        self._fin = None
        self._status_now = False
        offer = self._offer
        self.events.emit(now_s, "CLOSED", map_id=offer.map_id if offer else 0, how=how)

    def _answer_verified(self, session: int) -> bool:
        """Answer a packet of an already verified map's session with FIN(VERIFIED)."""
        for sess, map_id, _ in self._verified:
            if sess == session:
                self._replies.append(lp.encode(lp.Fin(sess, map_id, lp.FinStatus.VERIFIED)))
                return True
        return False

    def _answer_unknown(self, session: int, now_s: float, report: bool = True) -> None:
        """NO_SESSION to a sender whose session this receiver does not hold (rate-limited);
        ``report``: event UNKNOWN_SESSION the first time (a dropped session has its own)."""
        last = self._unknown.get(session)
        if last is not None and now_s - last < self.cfg.min_status_interval_s - _EPS:
            return
        if last is None:
            if len(self._unknown) >= 16:
                self._unknown.pop(next(iter(self._unknown)))
            if report:
                self.events.emit(now_s, "UNKNOWN_SESSION", session=session)
        self._unknown[session] = now_s
        self.stats.no_session += 1
        self._replies.append(lp.encode(lp.NoSession(session)))

    def _next_packet(self, now_s: float) -> bytes | None:
        if self._replies:
            return self._replies.popleft()
        since = now_s - self._last_status_s + _EPS
        if self._fin is not None and (self._status_now or self.state is ReceiverState.COMPLETE
                                      and since >= self.cfg.status_period_s):
            fin = self._fin
            if self.state is not ReceiverState.COMPLETE:
                self._fin = None  # a HASH_MISMATCH FIN is sent once per failed attempt
            self._status_now = False
            self._last_status_s = now_s
            return lp.encode(fin)
        if self.state is not ReceiverState.RECEIVING:
            self._status_now = False
            return None
        due = (self._status_now
               or (self._status_due and since >= self.cfg.min_status_interval_s)
               or (self._new_data and since >= self.cfg.status_period_s)
               or (self._n_rx == 0 and since >= self.cfg.min_status_interval_s
                   and now_s < self._start_s + self.cfg.keepalive_s)
               or since >= self.cfg.keepalive_s)
        if not due:
            return None
        self._status_now = self._status_due = self._new_data = False
        self._last_status_s = now_s
        self.stats.statuses += 1
        return lp.encode(self._status_packet())

    def _status_packet(self) -> lp.Status:
        offer = self._offer
        assert offer is not None
        limit = offer.n_segments if self._all_sent else self._highest
        end = min(limit, self._cum + 8 * self.cfg.max_bitmap_bytes)
        nbits = max(0, end - self._cum)
        bitmap = bytearray(-(-nbits // 8))
        for i in range(nbits):
            if self._have[self._cum + i]:
                bitmap[i >> 3] |= 1 << (i & 7)
        return lp.Status(offer.session, self._cum, self._highest, self._n_rx, self._echo,
                         bytes(bitmap))
