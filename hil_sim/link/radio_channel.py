"""Seeded radio channel model between the RECON-bot and the Cliff-bot (docs/algorithm.md §6.6).

Two independent directions (full duplex; ``reverse_loss`` gives side b -> a its own loss
probability, e.g. acknowledgements lost more often than data), each a serial line of ``rate_bps`` with a
drop-tail transmit queue, then a propagation ``latency_s`` (+ uniform ``jitter_s``). Every
packet independently may be lost (``loss``), have bits flipped (``ber`` per bit, binomial),
be duplicated (``duplicate``) or held back by up to ``reorder_delay_s`` (``reorder``), and is
lost if its time on the air overlaps an outage window. All randomness comes from one
``numpy`` generator per direction seeded from ``seed``, and time is whatever the caller
says, so a run with a seed is exactly repeatable and as fast as the CPU allows.

:class:`ChannelPort` wraps one side as an ``fsw.drivers.byte_port.BytePort`` driven by a
simulated clock, so bench code can treat the channel like any other radio.
"""

from __future__ import annotations

import heapq
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from fsw.drivers.byte_port import BytePort
from fsw.framework.params import param


@dataclass(frozen=True)
class RadioChannelConfig:
    """Impairments of the simulated radio (defaults: a clean 9600 bit/s link)."""

    rate_bps: float = param(9600.0, lo=100.0, hi=1e9, units="bit/s")
    latency_s: float = param(0.05, lo=0.0, hi=60.0, units="s")
    jitter_s: float = param(0.0, lo=0.0, hi=10.0, units="s")
    loss: float = param(0.0, lo=0.0, hi=1.0, doc="packet loss probability")
    reverse_loss: float = param(-1.0, lo=-1.0, hi=1.0,
                                doc="loss probability of side b -> a alone (the receiver's answers: "
                                "acknowledgements); -1: the same as loss")
    ber: float = param(0.0, lo=0.0, hi=0.1, doc="bit error rate")
    duplicate: float = param(0.0, lo=0.0, hi=1.0, doc="probability a packet arrives twice")
    reorder: float = param(0.0, lo=0.0, hi=1.0, doc="probability a packet is held back")
    reorder_delay_s: float = param(0.5, lo=0.0, hi=60.0, units="s")
    outages: tuple[tuple[float, float], ...] = field(
        default=(), metadata={"doc": "(start_s, duration_s) windows with no link"})
    queue_bytes: int = param(65536, lo=64, hi=1 << 30, units="B", doc="transmit queue limit")

    def __post_init__(self) -> None:
        if self.reverse_loss != -1.0 and not 0.0 <= self.reverse_loss <= 1.0:
            raise ValueError(f"reverse_loss {self.reverse_loss} is neither -1 nor in [0, 1]")


@dataclass
class DirectionStats:
    sent: int = 0
    delivered: int = 0
    lost: int = 0
    corrupted: int = 0
    duplicated: int = 0
    reordered: int = 0
    outage_drops: int = 0
    queue_drops: int = 0
    air_bytes: int = 0


class _Direction:
    def __init__(self, cfg: RadioChannelConfig, rng: np.random.Generator, loss: float) -> None:
        self.cfg = cfg
        self.rng = rng
        self.loss = loss
        self.line_free_s = 0.0
        self.heap: list[tuple[float, int, bytes]] = []
        self.order = 0
        self.stats = DirectionStats()

    def submit(self, datagram: bytes, now_s: float) -> None:
        cfg, rng, st = self.cfg, self.rng, self.stats
        st.sent += 1
        backlog_s = max(0.0, self.line_free_s - now_s)
        if backlog_s * cfg.rate_bps / 8.0 + len(datagram) > cfg.queue_bytes:
            st.queue_drops += 1
            return
        start = max(now_s, self.line_free_s)
        end = start + 8.0 * len(datagram) / cfg.rate_bps
        self.line_free_s = end
        st.air_bytes += len(datagram)
        if any(s < end and start < s + d for s, d in cfg.outages):
            st.outage_drops += 1
            return
        if rng.random() < self.loss:
            st.lost += 1
            return
        copies = 2 if rng.random() < cfg.duplicate else 1
        st.duplicated += copies - 1
        for _ in range(copies):
            data = self._flip_bits(datagram)
            t = end + cfg.latency_s + (rng.uniform(0.0, cfg.jitter_s) if cfg.jitter_s else 0.0)
            if rng.random() < cfg.reorder:
                st.reordered += 1
                t += rng.uniform(0.0, cfg.reorder_delay_s)
            heapq.heappush(self.heap, (t, self.order, data))
            self.order += 1

    def _flip_bits(self, datagram: bytes) -> bytes:
        nbits = 8 * len(datagram)
        nflip = int(self.rng.binomial(nbits, self.cfg.ber)) if self.cfg.ber > 0 else 0
        if nflip == 0:
            return datagram
        self.stats.corrupted += 1
        buf = np.frombuffer(datagram, np.uint8).copy()
        pos = self.rng.choice(nbits, size=min(nflip, nbits), replace=False)
        np.bitwise_xor.at(buf, pos >> 3, (1 << (pos & 7)).astype(np.uint8))
        return buf.tobytes()

    def due(self, now_s: float) -> list[bytes]:
        out = []
        while self.heap and self.heap[0][0] <= now_s:
            out.append(heapq.heappop(self.heap)[2])
        self.stats.delivered += len(out)
        return out

    def next_arrival_s(self) -> float | None:
        return self.heap[0][0] if self.heap else None


class RadioChannel:
    """The two directions: ``send("a", ...)`` travels to side ``"b"`` and vice versa."""

    def __init__(self, cfg: RadioChannelConfig | None = None, seed: int = 0) -> None:
        self.cfg = cfg or RadioChannelConfig()
        ss = np.random.SeedSequence(seed)
        ga, gb = (np.random.default_rng(s) for s in ss.spawn(2))
        back = self.cfg.loss if self.cfg.reverse_loss < 0 else self.cfg.reverse_loss
        self._dirs = {"a": _Direction(self.cfg, ga, self.cfg.loss), "b": _Direction(self.cfg, gb, back)}

    def send(self, side: str, datagram: bytes, now_s: float) -> None:
        """Side ``side`` puts a packet on the air at ``now_s``."""
        self._dirs[side].submit(bytes(datagram), now_s)

    def receive(self, side: str, now_s: float) -> list[bytes]:
        """Packets that have reached side ``side`` by ``now_s``."""
        return self._dirs["b" if side == "a" else "a"].due(now_s)

    def next_arrival_s(self) -> float | None:
        times = [t for t in (d.next_arrival_s() for d in self._dirs.values()) if t is not None]
        return min(times) if times else None

    def stats(self, side: str) -> DirectionStats:
        """Counters of what side ``side`` sent."""
        return self._dirs[side].stats


class ChannelPort(BytePort):
    """One side of a :class:`RadioChannel` as a radio, on a simulated clock."""

    def __init__(self, channel: RadioChannel, side: str, clock: Callable[[], float]) -> None:
        super().__init__(f"sim://{side}")
        self._ch, self._side, self._clock = channel, side, clock
        self._pending: list[bytes] = []

    def _send_internal(self, datagram: bytes) -> None:
        self._ch.send(self._side, datagram, self._clock())

    def _recv_internal(self, timeout_s: float, max_bytes: int) -> bytes | None:
        if not self._pending:
            self._pending = self._ch.receive(self._side, self._clock())
        return self._pending.pop(0) if self._pending else None
