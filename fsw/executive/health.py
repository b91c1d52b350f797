"""Health monitoring: pings every task, warns and declares fatal, strokes the watchdog.

Each activation the health task sends every other enabled task a new ping; a task answers
when it next completes an activation normally (``Task.answer_ping``). A task whose answer
is older than ``health_warn_frames`` (plus its rate-group divisor) raises WARNING_HI; older
than ``health_fatal_frames``, FATAL. The watchdog is stroked only while no task is fatal,
so a hung task, or a stalled executive that no longer runs this task, lets it expire.
"""

from __future__ import annotations

from typing import ClassVar

from fsw.framework.telemetry import Channel, EventDef, Severity
from fsw.tasks.base import FlightTask


class HealthTask(FlightTask):
    KIND: ClassVar[str] = "health"
    RATE_HZ: ClassVar[tuple[float, float]] = (0.5, 10.0)  # pings answered within health_warn_frames
    DOC: ClassVar[str] = "Pings every task; strokes the watchdog while all are alive."
    CHANNELS = (
        Channel("tasks_warning", "count", hi=0),
        Channel("tasks_fatal", "count", hi=0),
        Channel("watchdog_strokes", "count"),
    )
    EVENTS = (
        EventDef("TASK_LATE", Severity.WARNING_HI, "task {target} has not answered for {frames} frames"),
        EventDef(
            "TASK_HUNG", Severity.FATAL, "task {target} hung: no answer for {frames} frames; watchdog no longer stroked"
        ),
        EventDef("TASK_RECOVERED", Severity.ACTIVITY_HI, "task {target} answering again"),
    )

    def setup(self) -> None:
        e = self.ctx.cfg.executive
        self.warn_frames, self.fatal_frames = e.health_warn_frames, e.health_fatal_frames
        self.state: dict[str, str] = {}
        self._first_frame: int | None = None  # a resumed run starts at its checkpoint's frame
        self.strokes = 0
        runtime = self.ctx.runtime
        self._divisor = dict(runtime.schedule())

    def run(self, frame: int) -> None:
        runtime = self.ctx.runtime
        n_warn = n_fatal = 0
        if self._first_frame is None:
            self._first_frame = frame
        for name, div in self._divisor.items():
            task = runtime.tasks[name]
            if task is self or not runtime.is_enabled(name):
                self.state.pop(name, None)
                continue
            task.ping(frame)
            age = frame - max(task.ping_answered_frame, self._first_frame)  # not older than the monitor
            if task.ping_answered == task.ping_sent or age <= div:
                age = 0
            prev = self.state.get(name, "ok")
            if age > self.fatal_frames + div:
                now = "fatal"
            elif age > self.warn_frames + div:
                now = "warn"
            else:
                now = "ok"
            if now != prev:
                if now == "fatal":
                    self.event("TASK_HUNG", target=name, frames=age)
                elif now == "warn" and prev == "ok":
                    self.event("TASK_LATE", target=name, frames=age)
                elif now == "ok":
                    self.event("TASK_RECOVERED", target=name)
                self.state[name] = now
            n_warn += now == "warn"
            n_fatal += now == "fatal"
        watchdog = self.ctx.res.watchdog
        if n_fatal == 0 and watchdog is not None:
            watchdog.stroke()
            self.strokes += 1
        self.tlm("tasks_warning", n_warn)
        self.tlm("tasks_fatal", n_fatal)
        self.tlm("watchdog_strokes", self.strokes)
