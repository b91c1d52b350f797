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

import heapq
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple, Protocol

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
    """One telemetry channel offered to the downlink."""

    key: str  # NAMED_VALUE name
    value: Any
    out_of_limits: bool


class ChannelCell(Protocol):
    """Where a channel's latest value lives (``fsw.framework.telemetry.ChannelValue``)."""

    value: Any


@dataclass(frozen=True)
class ChannelTable:
    """Every channel the downlink may send, read live: ``(key, cell, lo, hi)`` rows, and the
    keys of the channels whose value changed since the scheduler last looked (``changed``,
    filled by the owner from the telemetry store's change set), so that the scheduler visits
    only those and the ones due for a refresh (:meth:`ChannelScheduler.ranked`)."""

    rows: tuple[tuple[str, ChannelCell, float | None, float | None], ...]
    changed: dict[str, None] = field(default_factory=dict)
    cells: dict[str, ChannelCell] = field(init=False, repr=False)
    limits: dict[str, tuple[float | None, float | None]] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "cells", {key: cell for key, cell, _, _ in self.rows})
        object.__setattr__(self, "limits", {key: (lo, hi) for key, _, lo, hi in self.rows
                                            if lo is not None or hi is not None})

    def samples(self) -> list[ChannelSample]:
        """Every numeric channel now (what :meth:`ChannelScheduler.due` ranks)."""
        out = []
        for key, cell, lo, hi in self.rows:
            v = cell.value
            if v is not None and not isinstance(v, str):
                out.append(ChannelSample(key, v, _outside(v, lo, hi)))
        return out


def _outside(v: Any, lo: float | None, hi: float | None) -> bool:
    return (lo is not None and v < lo) or (hi is not None and v > hi)


@dataclass
class ChannelScheduler:
    """Which channels go next (module docstring): ranked by (out of limits first, changed
    first, longest unsent, key), a channel at most every ``period_s``, an unchanged one
    again after ``refresh_s``."""

    period_s: float
    refresh_s: float
    last: dict[str, tuple[float, Any]] = field(default_factory=dict)  # key -> (time sent, value)
    sent: int = 0
    _order: dict[str, None] = field(default_factory=dict)  # table keys, longest unsent first
    _marked: list[str] = field(default_factory=list)  # sent since the order was last brought up to date
    _pending: dict[str, None] = field(default_factory=dict)  # changed (or never sent) and not sent since
    _ready: dict[str, None] = field(default_factory=dict)  # of those, the ones past their period
    _parked: list[tuple[float, str]] = field(default_factory=list)  # the others: heap of (time ready, key)

    def due(self, now_s: float, samples: Iterable[ChannelSample]) -> list[ChannelSample]:
        """Samples worth sending now, best first (deterministic order): every one ranked."""
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

    def ranked(self, now_s: float, table: ChannelTable) -> list[ChannelSample]:
        """:meth:`due` over ``table.samples()``: the same samples in the same order, found
        without visiting every channel (issue 15; a frame sends ~8 of ~200). Candidates are the
        channels never sent, those changed since they were sent (``table.changed``: pending
        until sent, parked in a heap until ``period_s`` has passed), and, walking the channels
        longest unsent first until one is younger than ``refresh_s``, the unchanged ones to
        refresh."""
        self._catch_up(table)
        pending, ready, parked = self._pending, self._ready, self._parked
        last, cells, limits = self.last, table.cells, table.limits
        period, refresh = self.period_s - 1e-9, self.refresh_s - 1e-9
        for key in table.changed:  # pending until sent: ready once its period has passed
            if key not in pending:
                pending[key] = None
                prev = last.get(key)
                if prev is not None and now_s - prev[0] < period:
                    heapq.heappush(parked, (prev[0] + period, key))
                else:
                    ready[key] = None
        table.changed.clear()
        early: list[tuple[float, str]] = []
        while parked and parked[0][0] <= now_s + 1e-6:
            t, key = heapq.heappop(parked)
            prev = last.get(key)
            if key not in pending or key in ready or prev is None:
                continue
            if now_s - prev[0] < period:
                if t == prev[0] + period:
                    early.append((t, key))  # not yet (by rounding): again next time
                continue  # else a stale entry: sent and pending again since, parked anew
            ready[key] = None
        for item in early:
            heapq.heappush(parked, item)
        ranked: list[tuple[tuple[int, int, float, str], ChannelSample]] = []
        for key in list(ready):
            prev = last.get(key)
            v = cells[key].value
            if v is None or isinstance(v, str):  # not a number: pending again when written anew
                del pending[key], ready[key]
                continue
            if prev is not None and same_value(prev[1], v):
                del pending[key], ready[key]  # back to the value sent: unchanged (refreshed below if due)
                continue
            out = key in limits and _outside(v, *limits[key])
            ranked.append(((0 if out else 1, 0, prev[0] if prev is not None else -math.inf, key),
                           ChannelSample(key, v, out)))
        for key in self._order:
            prev = last.get(key)
            if prev is None:
                continue  # never sent: pending
            if now_s - prev[0] < refresh:
                break  # every later one was sent later
            v = cells[key].value
            if key in pending or v is None or isinstance(v, str):
                continue
            out = key in limits and _outside(v, *limits[key])
            changed = not same_value(prev[1], v)  # True only for a value written past the store
            ranked.append(((0 if out else 1, 0 if changed else 1, prev[0], key), ChannelSample(key, v, out)))
        ranked.sort(key=lambda r: r[0])
        return [s for _, s in ranked]

    def mark(self, now_s: float, sample: ChannelSample) -> None:
        self.last[sample.key] = (now_s, sample.value)
        self.sent += 1
        if self._order:
            self._marked.append(sample.key)
            self._pending.pop(sample.key, None)
            self._ready.pop(sample.key, None)

    def _catch_up(self, table: ChannelTable) -> None:
        """The order brought up to date: channels sent since the last call go to its end, by
        (time sent, key). The first call orders every channel so (never sent first) and makes
        every channel pending."""
        order, last = self._order, self.last
        if not order:
            self._order = dict.fromkeys(sorted(table.cells, key=lambda k: (last[k][0] if k in last else -math.inf, k)))
            self._pending = dict.fromkeys(table.cells)
            self._ready = dict.fromkeys(table.cells)
            self._parked = []
        else:
            for key in sorted(set(self._marked), key=lambda k: (last[k][0], k)):
                if key in order:
                    del order[key]
                    order[key] = None
        self._marked.clear()


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


def coalesce(frames: Sequence[bytes], max_bytes: int) -> list[bytes]:
    """The frames of one activation joined into as few packets of at most ``max_bytes`` as
    whole frames allow (a frame longer than ``max_bytes`` goes alone, for the port to refuse).
    MAVLink is a byte stream: ArduPilot, MAVProxy and mavlink-router put several frames in one
    UDP datagram, and pymavlink and QGroundControl parse them; one send per activation instead
    of one per frame (issue 15)."""
    packets: list[bytes] = []
    batch: list[bytes] = []
    size = 0
    for f in frames:
        if batch and size + len(f) > max_bytes:
            packets.append(b"".join(batch))
            batch, size = [], 0
        batch.append(f)
        size += len(f)
    if batch:
        packets.append(b"".join(batch))
    return packets
