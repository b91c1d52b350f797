"""The two tasks of a small second agent kind for the agent/topology tests (``probe``)."""

from __future__ import annotations

from typing import ClassVar

from fsw.framework.task import Task
from fsw.framework.telemetry import Channel, EventDef, Severity

BEAT = "probe.beat"


class BeaconTask(Task):
    """Publishes a numbered beat, with the clock time, every activation."""

    KIND: ClassVar[str] = "beacon"
    CHANNELS = (Channel("beats", "count"),)

    def setup(self) -> None:
        self.beats = 0

    def run(self, frame: int) -> None:
        self.beats += 1
        self.publish(BEAT, (self.beats, frame, self.ctx.clock.now()))
        self.tlm("beats", self.beats)


class ListenerTask(Task):
    """Takes the beats (in a slower rate group) and says how many it heard."""

    KIND: ClassVar[str] = "listener"
    CHANNELS = (Channel("heard", "count"),)
    EVENTS = (EventDef("HEARD", Severity.ACTIVITY_LO, "heard beats {first}..{last} at {t:.1f} s"),)

    def setup(self) -> None:
        self.box = self.subscribe(BEAT, depth=16)
        self.heard: list[tuple[int, int, float]] = []

    def run(self, frame: int) -> None:
        got = self.box.drain()
        if got:
            self.heard.extend(got)
            self.event("HEARD", first=got[0][0], last=got[-1][0], t=self.ctx.clock.now())
        self.tlm("heard", len(self.heard))
