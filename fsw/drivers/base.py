"""What every device driver shares: a fault word, held error flags and queued events.

A driver never talks to the executive. It declares its events (``EVENTS``, F Prime style, so the
task that polls it can register them), queues them as ``(name, args)`` for that task to emit,
and keeps a fault word whose bits it names in ``FAULTS``. Transient errors (a bad frame, a
failed send) set a *held* bit that clears itself after ``error_hold_s`` without a new error, so
a fault is visible in telemetry for a while but does not latch on line noise.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

from fsw.framework.events import EventSink
from fsw.framework.telemetry import EventDef


class DriverBase:
    """Fault word, held error bits and the event queue of one device driver."""

    EVENTS: ClassVar[tuple[EventDef, ...]] = ()
    FAULTS: ClassVar[dict[str, int]] = {}

    def __init__(self, error_hold_s: float = 2.0, max_events: int = 256) -> None:
        self.faults = 0
        self.error_hold_s = error_hold_s
        self._held_until: dict[int, float] = {}
        self._events = EventSink(max_events)
        self.last_poll_s: float | None = None  # time of the last poll(), so a task can tell

    # -- events -----------------------------------------------------------------------------
    def _event(self, name: str, **args: Any) -> None:
        self._events.emit(self.last_poll_s if self.last_poll_s is not None else math.nan, name, **args)

    def drain_events(self) -> list[tuple[str, dict[str, Any]]]:
        """Events raised since the last call, oldest first."""
        return [(ev.name, ev.args) for ev in self._events.pop_all()]

    @property
    def events_dropped(self) -> int:
        return self._events.dropped

    # -- faults -----------------------------------------------------------------------------
    def _set(self, bit: int, on: bool = True) -> None:
        self.faults = (self.faults | bit) if on else (self.faults & ~bit)

    def _hold(self, bit: int, now: float) -> None:
        """Set ``bit`` until ``error_hold_s`` passes without another call."""
        self._held_until[bit] = now + self.error_hold_s
        self._set(bit)

    def _expire_holds(self, now: float) -> None:
        for bit, until in list(self._held_until.items()):
            if now >= until:
                self._set(bit, False)
                del self._held_until[bit]

    def has(self, bit: int) -> bool:
        return bool(self.faults & bit)

    def fault_names(self) -> list[str]:
        return [n for n, b in self.FAULTS.items() if self.faults & b]

    @property
    def fault(self) -> bool:
        """The driver's fault flag: any fault bit set."""
        return self.faults != 0
