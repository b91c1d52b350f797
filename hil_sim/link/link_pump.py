"""Real-time driver loop for one end of the map link (docs/algorithm.md §6.6; docs/link.md).

The link ends are sans-I/O (``receive``, ``poll``, ``next_deadline_s``); this is the loop
that runs one over a real radio (``fsw.drivers.radio``) on a monotonic clock, used by the
``safer-hil send-map`` and ``safer-hil cliffbot`` processes. It sleeps in ``select`` until
the earlier of the end's next deadline and the next datagram, so packets leave when the
pacer allows, not at the next tick of a polling period (a 20 ms tick costs a 9600 bit/s
link about 2.5 % of its capacity).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Protocol

from fsw.comm.link import LinkConfig
from fsw.drivers.radio import RadioPort


class LinkEnd(Protocol):
    def receive(self, datagram: bytes, now_s: float) -> None: ...

    def poll(self, now_s: float) -> list[bytes]: ...

    def next_deadline_s(self) -> float | None: ...


def monotonic_clock() -> Callable[[], float]:
    """Seconds since this call, on the monotonic clock."""
    t0 = time.monotonic()
    return lambda: time.monotonic() - t0


def pump_once(end: LinkEnd, port: RadioPort, clock: Callable[[], float], max_wait_s: float) -> int:
    """Wait for a datagram or the end's deadline (at most ``max_wait_s``), feed, send.

    Returns the number of datagrams received.
    """
    now = clock()
    deadline = end.next_deadline_s()
    wait = max_wait_s if deadline is None else min(max_wait_s, max(0.0, deadline - now))
    d = port.recv(wait, now)
    now = clock()
    n = 0
    while d is not None:
        end.receive(d, now)
        n += 1
        d = port.recv(0.0, now)
    for pkt in end.poll(now):
        port.send(pkt, now)
    return n


def load_link_config(path: str | Path | None, rate_bps: float | None = None) -> LinkConfig:
    """``[link]`` of a flight config (default config/fsw.toml), its bit rate replaced by
    ``rate_bps`` when given; ``ConfigError`` (or ``ValueError`` for a bad rate) if invalid."""
    import math

    from fsw.framework.params import build, load_toml
    from fsw.settings import DEFAULT_CONFIG

    src = str(path or DEFAULT_CONFIG)
    link = build(LinkConfig, load_toml(src).get("link", {}), src, "link")
    if rate_bps is None:
        return link
    if not (math.isfinite(rate_bps) and rate_bps >= 300):
        raise ValueError("--rate-bps must be a finite number >= 300")
    return LinkConfig(**{**vars(link), "rate_bps": rate_bps})
