"""Downlink scheduling: a per-frame byte budget filled in priority order, with rate limits.

* :class:`Packer` packs messages into wire frames only while they fit the frame's budget
  (exact sizes: MAVLink 2 trims trailing zero payload bytes, signing adds 13). A message
  that does not fit is *not* packed, so sequence numbers and signing timestamps never skip:
  a gap in ``seq`` at the ground always means a lost frame.
* :class:`DownlinkQueue` holds executive events waiting for STATUSTEXT (a priority queue,
  not an event sink): most severe first, bounded (the least severe, newest, is dropped when
  full), released through a token bucket. Its counters are
  exact: ``seen = sent + dropped + filtered + queued``.
* :class:`ChannelScheduler` chooses which telemetry channels go next: a channel at most
  every ``period_s``; channels out of their limits first, then changed ones, then the
  longest unsent; unchanged values are refreshed every ``refresh_s``.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple

from fsw.comm.mavlink_dialect import SIGNATURE_LEN, mavlink, new_codec
from fsw.framework.telemetry import Event, Severity


class Packer:
    """Packs messages with the link's codec within ``budget`` bytes per frame."""

    def __init__(self, codec: mavlink.MAVLink) -> None:
        self.codec = codec
        self._sizer = new_codec(codec.srcSystem, codec.srcComponent)
        self.frames: list[bytes] = []
        self.used = 0
        self.budget = 0
        self.deferred = 0

    def begin(self, budget: int) -> None:
        self.frames, self.used, self.budget = [], 0, budget

    def size(self, msg: mavlink.MAVLink_message) -> int:
        signed = SIGNATURE_LEN if self.codec.signing.sign_outgoing else 0
        return len(msg.pack(self._sizer)) + signed

    def offer(self, msgs: Sequence[mavlink.MAVLink_message]) -> bool:
        """Pack all of ``msgs`` if together they fit the remaining budget, else none.

        Each message is packed once, with the link's codec; if the lot does not fit, the
        codec's sequence number and signing timestamp (the only state a pack advances) are
        put back, so nothing skips (the same frames as sizing first, at half the packing)."""
        codec = self.codec
        seq0, ts0 = codec.seq, codec.signing.timestamp
        bufs, need = [], 0
        for m in msgs:
            buf = bytes(m.pack(codec))
            codec.seq = (codec.seq + 1) % 256
            bufs.append(buf)
            need += len(buf)
        if self.used + need > self.budget:
            codec.seq, codec.signing.timestamp = seq0, ts0
            self.deferred += 1
            return False
        self.frames.extend(bufs)
        self.used += need
        return True

    @property
    def remaining(self) -> int:
        return self.budget - self.used


@dataclass
class TokenBucket:
    rate_hz: float
    burst: int
    tokens: float = 0.0
    last_s: float | None = None

    def refill(self, now_s: float) -> None:
        if self.last_s is None:
            self.tokens = float(self.burst)
        else:
            self.tokens = min(float(self.burst), self.tokens + (now_s - self.last_s) * self.rate_hz)
        self.last_s = now_s

    def take(self) -> bool:
        if self.tokens >= 1.0:
            self.tokens -= 1.0
            return True
        return False


@dataclass
class DownlinkQueue:
    """Bounded, severity-ordered events waiting for STATUSTEXT."""

    depth: int
    min_severity: Severity
    bucket: TokenBucket
    seen: int = 0
    sent: int = 0
    dropped: int = 0
    filtered: int = 0
    _items: list[tuple[int, int, Event]] = field(default_factory=list)
    _seq: int = 0

    def push(self, ev: Event) -> None:
        self.seen += 1
        if ev.severity > self.min_severity:
            self.filtered += 1
            return
        self._seq += 1
        self._items.append((int(ev.severity), self._seq, ev))
        if len(self._items) > self.depth:
            worst = max(self._items, key=lambda it: (it[0], it[1]))
            self._items.remove(worst)
            self.dropped += 1

    def head(self) -> Event | None:
        if not self._items:
            return None
        return min(self._items, key=lambda it: (it[0], it[1]))[2]

    def pop(self) -> None:
        best = min(self._items, key=lambda it: (it[0], it[1]))
        self._items.remove(best)
        self.sent += 1

    def __len__(self) -> int:
        return len(self._items)


class ChannelSample(NamedTuple):
    """One telemetry channel offered to the downlink (a tuple: ~190 are built every frame)."""

    key: str  # NAMED_VALUE name
    value: Any
    out_of_limits: bool


@dataclass
class ChannelScheduler:
    period_s: float
    refresh_s: float
    last: dict[str, tuple[float, Any]] = field(default_factory=dict)  # key -> (time sent, value)
    sent: int = 0

    def due(self, now_s: float, samples: Iterable[ChannelSample]) -> list[ChannelSample]:
        """Samples worth sending now, best first (deterministic order)."""
        ranked = []
        last = self.last
        for s in samples:
            prev = last.get(s.key)
            if prev is None:
                ranked.append(((0 if s.out_of_limits else 1, 0, -math.inf, s.key), s))
                continue
            if now_s - prev[0] < self.period_s - 1e-9:
                continue
            changed = not same_value(prev[1], s.value)
            if not changed and now_s - prev[0] < self.refresh_s - 1e-9:
                continue
            ranked.append(((0 if s.out_of_limits else 1, 0 if changed else 1, prev[0], s.key), s))
        ranked.sort(key=lambda r: r[0])
        return [s for _, s in ranked]

    def mark(self, now_s: float, sample: ChannelSample) -> None:
        self.last[sample.key] = (now_s, sample.value)
        self.sent += 1


def same_value(a: Any, b: Any) -> bool:
    """Equal for the channel scheduler (NaN equals NaN; values that cannot compare differ).
    Called for ~150 channels a frame: the common case (equal) is one comparison."""
    try:
        if a == b:
            return True
    except (TypeError, ValueError):
        return False
    return isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b)


@dataclass
class Periodic:
    """A message due every ``period_s`` (average rate kept, no burst after a stall)."""

    period_s: float
    next_s: float = 0.0

    def due(self, now_s: float) -> bool:
        return now_s >= self.next_s - 1e-9

    def done(self, now_s: float) -> None:
        self.next_s = max(self.next_s + self.period_s, now_s + 0.5 * self.period_s)
