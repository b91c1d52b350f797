"""Clocks for the executive: real time with absolute deadlines, and a stepped clock.

Frame ``k`` starts at ``start + k * period`` on both, so the period never drifts with the
work done in a frame (never ``sleep(period)`` after the work). The stepped clock is
advanced by whoever drives the executive (the HIL simulator in lockstep), so runs are
deterministic and faster than real time.
"""

from __future__ import annotations

import time
from typing import Protocol


class Clock(Protocol):
    """What the executive needs of a clock."""

    realtime: bool

    def now(self) -> float:
        """Seconds since the clock's epoch."""
        ...

    def sleep_until(self, t: float) -> None:
        """Block until ``now() >= t`` (a no-op for a stepped clock)."""
        ...


class MonotonicClock:
    """``time.monotonic`` based real-time clock; epoch at construction."""

    realtime = True

    def __init__(self) -> None:
        self._t0 = time.monotonic()

    def now(self) -> float:
        return time.monotonic() - self._t0

    def sleep_until(self, t: float) -> None:
        while True:
            remaining = t - self.now()
            if remaining <= 0:
                return
            time.sleep(remaining)


class SteppedClock:
    """Simulated time, advanced explicitly; ``sleep_until`` jumps forward."""

    realtime = False

    def __init__(self, start_s: float = 0.0) -> None:
        self._t = float(start_s)

    def now(self) -> float:
        return self._t

    def advance(self, dt_s: float) -> None:
        if dt_s < 0:
            raise ValueError("a clock cannot go backwards")
        self._t += dt_s

    def sleep_until(self, t: float) -> None:
        if t > self._t:
            self._t = t
