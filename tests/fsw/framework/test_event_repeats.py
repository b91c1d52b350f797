"""Issue 29, item 3: repeated identical events are counted and summarised, never lost when something changes."""

from __future__ import annotations

from fsw.framework.clock import SteppedClock
from fsw.framework.telemetry import EventDef, EventLog, Severity


def _log() -> tuple[SteppedClock, EventLog]:
    clock = SteppedClock()
    log = EventLog(clock.now, repeat_window_s=10.0)
    log.register("a.POLL", EventDef("POLL", Severity.WARNING_LO, "poll from {src}"))
    log.register("a.LINK", EventDef("LINK", Severity.ACTIVITY_HI, "link {state}"))
    log.register("b.POLL", EventDef("POLL", Severity.WARNING_LO, "poll from {src}"))
    return clock, log


def test_identical_events_within_the_window_are_counted_then_reported_with_their_count() -> None:
    clock, log = _log()
    for _ in range(50):  # one every 0.5 s for 25 s
        log.emit("a.POLL", src="1/1")
        clock.advance(0.5)
    texts = [e.text for e in log.history]
    assert texts[0] == "poll from 1/1" and len(texts) == 3  # at 0 s, 10 s, 20 s
    assert texts[1] == "poll from 1/1 (+19 identical in 10 s)"
    assert log.count("a.POLL") == 50 and log.repeats == 47


def test_a_change_in_between_is_never_held_back() -> None:
    clock, log = _log()
    log.emit("a.LINK", state="up")
    log.emit("a.LINK", state="lost")
    log.emit("a.LINK", state="up")  # identical to the first, but something changed in between
    log.emit("a.POLL", src="1/1")
    log.emit("a.POLL", src="2/1")  # another text: a new event
    log.emit("b.POLL", src="1/1")  # another component
    assert [e.text for e in log.history] == ["link up", "link lost", "link up", "poll from 1/1", "poll from 2/1",
                                             "poll from 1/1"]
