"""Telemetry channels and events, declared as data next to the task that owns them.

Channels carry units and limits and keep their latest value; events carry an F Prime
severity, a format string and a throttle. Event counters are exact even while the
throttle suppresses emission; a throttle reopens one slot per ``decay`` call, which the
executive makes on good frames (as in F Prime). An event identical (name and text) to
the last one its component emitted, within ``repeat_window_s`` of it, says nothing new: it is
counted, not emitted, and the next identical one after the window carries the count
(``(+N identical in T s)``). Anything else the component says in between ends the run, so
an event that says something changed is never held back.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from enum import IntEnum
from typing import Any


class Severity(IntEnum):
    """F Prime event severities, most severe first."""

    FATAL = 1
    WARNING_HI = 2
    WARNING_LO = 3
    COMMAND = 4
    ACTIVITY_HI = 5
    ACTIVITY_LO = 6
    DIAGNOSTIC = 7


@dataclass(frozen=True)
class Channel:
    """A telemetry channel declaration: ``name`` is local to the owning task."""

    name: str
    units: str = ""
    lo: float | None = None
    hi: float | None = None
    doc: str = ""


@dataclass(frozen=True)
class EventDef:
    """An event declaration. ``throttle`` = emissions before suppression (0: never throttled)."""

    name: str
    severity: Severity
    fmt: str
    throttle: int = 0
    doc: str = ""


@dataclass(frozen=True)
class Event:
    """One emitted event."""

    time_s: float
    event_id: int
    name: str
    severity: Severity
    text: str


@dataclass
class ChannelValue:
    value: float | int | str | None = None
    time_s: float = math.nan
    updates: int = 0
    name: str = ""  # the full name, for the store's change set


def differs(a: object, b: object) -> bool:
    """``a != b`` for the change set; values that cannot compare differ (NaN differs from NaN:
    a reader compares with what it last used)."""
    try:
        return bool(a != b)
    except (TypeError, ValueError):
        return True


class TelemetryStore:
    """Latest value of every channel, keyed by full name ``task.channel``."""

    def __init__(self) -> None:
        self.defs: dict[str, Channel] = {}
        self.ids: dict[str, int] = {}
        self.values: dict[str, ChannelValue] = {}
        # full names of the channels written with a new value since the ground link last took
        # them (its only reader, ``fsw.tasks.mavlink_view``): it then visits those, not all
        self.changed: dict[str, None] = {}

    def register(self, full_name: str, chan: Channel) -> None:
        if full_name in self.defs:
            raise ValueError(f"telemetry channel {full_name} declared twice")
        self.ids[full_name] = len(self.defs) + 1
        self.defs[full_name] = chan
        self.values[full_name] = ChannelValue(name=full_name)

    def write(self, full_name: str, value: float | int | str, time_s: float) -> None:
        cv = self.values[full_name]  # KeyError = undeclared channel: a software bug
        if differs(value, cv.value):
            self.changed[full_name] = None
        cv.value, cv.time_s = value, time_s
        cv.updates += 1

    def get(self, full_name: str) -> Any:
        return self.values[full_name].value

    def limit_state(self, full_name: str) -> str:
        """``ok``, ``low``, ``high`` or ``none`` (no value yet)."""
        chan, v = self.defs[full_name], self.values[full_name].value
        if v is None or isinstance(v, str):
            return "none" if v is None else "ok"
        if chan.lo is not None and v < chan.lo:
            return "low"
        if chan.hi is not None and v > chan.hi:
            return "high"
        return "ok"

    def snapshot(self) -> dict[str, Any]:
        return {k: v.value for k, v in self.values.items()}


@dataclass
class _EventState:
    count: int = 0
    suppressed: int = 0
    open_slots_used: int = 0


class EventLog:
    """Emits events to listeners and a bounded history, with throttles and exact counters."""

    def __init__(self, now: Callable[[], float], history: int = 1000, repeat_window_s: float = 10.0) -> None:
        self._now = now
        self.repeat_window_s = repeat_window_s
        self._last: dict[str, list[Any]] = {}  # component -> [(name, text), time emitted, repeats held]
        self.repeats = 0  # identical events counted, not emitted
        self.defs: dict[str, EventDef] = {}
        self.ids: dict[str, int] = {}
        self._state: dict[str, _EventState] = {}
        self.history: deque[Event] = deque(maxlen=history)
        self.listeners: list[Callable[[Event], None]] = []

    def register(self, full_name: str, ev: EventDef) -> None:
        if full_name in self.defs:
            raise ValueError(f"event {full_name} declared twice")
        self.ids[full_name] = len(self.defs) + 1
        self.defs[full_name] = ev
        self._state[full_name] = _EventState()

    def emit(self, full_name: str, **args: Any) -> Event | None:
        """Count the event and, unless throttled, format and deliver it."""
        ev = self.defs[full_name]
        st = self._state[full_name]
        st.count += 1
        if ev.throttle and st.open_slots_used >= ev.throttle:
            st.suppressed += 1
            return None
        try:
            text = ev.fmt.format(**args)
        except (KeyError, IndexError, ValueError) as exc:  # a format bug must not crash flight code
            text = f"{ev.fmt} (format error: {exc!r}; args={args})"
        now, owner, key = self._now(), full_name.split(".", 1)[0], (full_name, text)
        last = self._last.get(owner)
        if last is not None and last[0] == key:
            if now - last[1] < self.repeat_window_s:
                last[2] += 1
                st.suppressed += 1
                self.repeats += 1
                return None
            if last[2]:
                text += f" (+{last[2]} identical in {now - last[1]:.0f} s)"
        self._last[owner] = [key, now, 0]
        st.open_slots_used += 1
        if ev.throttle and st.open_slots_used == ev.throttle:
            text += " [throttled]"
        event = Event(now, self.ids[full_name], full_name, ev.severity, text)
        self.history.append(event)
        for listener in self.listeners:
            listener(event)
        return event

    def decay(self, full_name: str) -> None:
        """Reopen one throttle slot (called on good frames)."""
        st = self._state[full_name]
        if st.open_slots_used > 0:
            st.open_slots_used -= 1

    def reset_throttle(self, full_name: str) -> None:
        self._state[full_name].open_slots_used = 0

    def count(self, full_name: str) -> int:
        return self._state[full_name].count

    def suppressed(self, full_name: str) -> int:
        return self._state[full_name].suppressed

    def throttled(self, full_name: str) -> bool:
        ev = self.defs[full_name]
        return bool(ev.throttle) and self._state[full_name].open_slots_used >= ev.throttle
