"""The watchdog: anything that can be stroked, and a software one on an injected clock.

The health task strokes it while every task answers its pings (docs/architecture.md,
"The cyclic executive", Health); a hung task, or a stalled executive, lets it expire.
"""

from __future__ import annotations

from typing import Protocol

from fsw.framework.clock import Clock


class Watchdog(Protocol):
    def stroke(self) -> None: ...


class SoftwareWatchdog:
    """A watchdog timer on a clock: expired once ``timeout_s`` passes without a stroke."""

    def __init__(self, clock: Clock, timeout_s: float) -> None:
        self.clock, self.timeout_s = clock, timeout_s
        self.last_stroke_s = clock.now()
        self.strokes = 0

    def stroke(self) -> None:
        self.last_stroke_s = self.clock.now()
        self.strokes += 1

    def expired(self) -> bool:
        return self.clock.now() - self.last_stroke_s > self.timeout_s
