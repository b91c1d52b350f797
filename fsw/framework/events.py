"""The event sink of code that runs without the executive: drivers and sans-I/O protocols.

A driver or a protocol state machine cannot emit executive events (it never sees the
executive); it queues them here, each with the time it happened and its arguments, and the
task that owns it drains the sink every activation and re-emits them under its own name
(F Prime: a component's events go out through its own ports). The sink is bounded: when it is
full the oldest event is dropped and counted, so a flood never grows memory.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Any


@dataclass(frozen=True)
class PendingEvent:
    """An event waiting for its owner task; ``name`` matches the owner's event table."""

    time_s: float
    name: str
    args: dict[str, Any] = field(default_factory=dict)


class EventSink:
    """Bounded FIFO of :class:`PendingEvent` (oldest dropped first; ``dropped`` counts them)."""

    def __init__(self, maxlen: int = 64) -> None:
        self._q: deque[PendingEvent] = deque(maxlen=maxlen)
        self.dropped = 0

    def emit(self, time_s: float, name: str, **args: Any) -> None:
        if len(self._q) == self._q.maxlen:
            self.dropped += 1
        self._q.append(PendingEvent(time_s, name, args))

    def pop_all(self) -> list[PendingEvent]:
        """Every queued event, oldest first; the sink is empty afterwards."""
        out = list(self._q)
        self._q.clear()
        return out

    def __len__(self) -> int:
        return len(self._q)
