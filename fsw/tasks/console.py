"""Prints a one-line telemetry summary and new events to stdout (bench and demo use).

Ground operators use MAVLink; this task is for a person watching ``safer-fsw run`` or the
lockstep demo in a terminal.
"""

from __future__ import annotations

import sys
from typing import ClassVar, TextIO

from fsw.framework.telemetry import Event, Severity
from fsw.tasks.base import FlightTask


class ConsoleTask(FlightTask):
    KIND: ClassVar[str] = "console"
    RATE_HZ: ClassVar[tuple[float, float]] = (0.1, 10.0)
    DOC: ClassVar[str] = "Prints a telemetry summary line per activation and every event."

    out: TextIO | None = None  # None: whatever sys.stdout is when printing

    def setup(self) -> None:
        self.ctx.events.listeners.append(self._on_event)
        self.min_severity = Severity.ACTIVITY_LO

    def _on_event(self, ev: Event) -> None:
        if ev.severity <= self.min_severity:
            print(f"[{ev.time_s:9.2f}] {ev.severity.name:<11} {ev.name}: {ev.text}", file=self.out or sys.stdout)

    def run(self, frame: int) -> None:
        exe = self.ctx.runtime
        worst = max(((t.max_s, n) for n, t in exe.tasks.items() if n != "exec"), default=(0.0, "-"))
        print(
            f"[{self.ctx.clock.now():9.2f}] frame {frame:6d}  slips {exe.slips}  "
            f"overruns {sum(t.overruns for t in exe.tasks.values())}  "
            f"jobs {exe.jobs.pending}  worst task {worst[1]} {worst[0] * 1e3:.2f} ms",
            file=self.out or sys.stdout,
        )
